// camera.h: pinhole camera with jittered supersampling. A sample's ray passes
// through a uniformly random point of its pixel, so a pixel is the box-filtered
// mean of its samples. The host computes the image-plane frame:
//   corner  direction to the top-left corner of the image (plane at distance 1)
//   dx, dy  steps of one pixel to the right and down

inline V3 camera_ray(real4 corner, real4 dx, real4 dy, vreal px, vreal py)
{
    V3 d = v3(corner.x + px * dx.x + py * dy.x,
              corner.y + px * dx.y + py * dy.y,
              corner.z + px * dx.z + py * dy.z);
    return v3_normalize(d);
}
