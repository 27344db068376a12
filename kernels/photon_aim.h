// photon_aim.h: where caustic photons are sent. Each photon leaves a light
// in a direction aimed at the caustic casters (purely specular objects, scene
// records after the lights: bounding sphere centre and radius, radius < 0
// for an unbounded one). aim_mode 0 picks a caster in proportion to the solid
// angle of its bounding cone weighted by the largest cosine at the light
// inside it; aim_mode 1 picks casters equally, as in the paper. The direction
// is uniform in the chosen cone and its pdf is the mixture over every cone
// that contains it (aim_pdf), which the camera side also evaluates for the
// multiple-importance weights of photon merging.

typedef struct {
    V3 w;         // direction
    vreal pdf;    // solid-angle pdf of w (mixture over the cones)
    vmask valid;
} AimSample;

inline real4 caster_sphere(const Scene *sc, uint j)
{
    return scene_rec(sc, OFF_CAUSTICS + CAUSTIC_STRIDE * j + CAUSTIC_SPHERE);
}

// Cone from y around caster obj's bounding sphere (the whole sphere of
// directions, omc = 2, when y is inside it or the caster is unbounded), and
// the caster's pick weight.
inline vreal caster_cone(real4 obj, V3 y, V3 n, vmask two_sided, uint aim_mode, V3 *axis, vreal *omc)
{
    V3 dc = v3_sub(v3_splat(obj), y);
    vreal d2 = v3_dot(dc, dc);
    vmask full = (obj.w < R(0)) || d2 <= obj.w * obj.w;
    *omc = VSEL(sphere_cone_omc(obj.w * obj.w, d2), (vreal)R(2), full);  // 1 - cos(theta_max)
    *axis = v3_scale(dc, vrsqrt(d2));
    if (aim_mode != 0)
        return (vreal)R(1);
    // Solid angle times the largest cosine at the light within the cone: zero
    // only for a cone wholly behind the light's emitting side.
    vreal c = v3_dot(*axis, n);
    c = VSEL(c, fabs(c), two_sided);
    vreal s = vsafe_sqrt(R(1) - c * c);
    vreal cos_max = R(1) - *omc, sin_max = vsafe_sqrt(*omc * (R(2) - *omc));
    vreal best = VSEL(c * cos_max + s * sin_max, (vreal)R(1), full || c >= cos_max);
#if CLPT_HAS_DELTA_LIGHTS
    best = VSEL(best, (vreal)R(1), v3_dot(n, n) == R(0));  // a point light: every direction alike
#endif
    return R(2 * M_PI) * *omc * fmax(best, R(0));
}

// Solid-angle pdf of direction w from light point y (normal n) under
// aim_at_casters: the mixture over every caster cone that contains w.
inline vreal aim_pdf(const Scene *sc, V3 y, V3 n, vmask two_sided, uint aim_mode, V3 w)
{
    V3 axis;
    vreal omc;
    vreal total = (vreal)R(0), pdf = (vreal)R(0);
    for (uint j = 0; j < NUM_CAUSTICS; j++) {
        vreal wj = caster_cone(caster_sphere(sc, j), y, n, two_sided, aim_mode, &axis, &omc);
        vmask inside = omc >= R(2) || v3_dot(w, axis) >= R(1) - omc;
        total += wj;
        pdf += VSEL((vreal)R(0), wj * uniform_cone_pdf(omc), inside && wj > R(0));
    }
    return VSEL((vreal)R(0), pdf / total, total > R(0));
}

inline AimSample aim_at_casters(const Scene *sc, V3 y, V3 n, vmask two_sided, uint aim_mode, vreal u0,
                                vreal u1, vreal u2)
{
    AimSample a;
    V3 axis;
    vreal omc;
    vreal total = (vreal)R(0);
    for (uint j = 0; j < NUM_CAUSTICS; j++)
        total += caster_cone(caster_sphere(sc, j), y, n, two_sided, aim_mode, &axis, &omc);
    // Pick a caster by weight, and a direction uniform in its cone.
    vreal pick = u0 * total, acc = (vreal)R(0);
    vmask taken = total != total;
    a.w = v3_zero();
    for (uint j = 0; j < NUM_CAUSTICS; j++) {
        vreal w = caster_cone(caster_sphere(sc, j), y, n, two_sided, aim_mode, &axis, &omc);
        acc += w;
        vmask sel = !taken && w > R(0) && (pick < acc || j + 1 == NUM_CAUSTICS);
        taken = taken || sel;
        V3 lc = sample_uniform_cone(u1, u2, omc);
        a.w = v3_sel(a.w, frame_to_world(axis, lc.x, lc.y, lc.z), sel);
    }
    vreal pdf = aim_pdf(sc, y, n, two_sided, aim_mode, a.w);
    a.pdf = pdf;
    a.valid = taken && total > R(0) && pdf > R(0);
    return a;
}


// The light-side pdf factor pf = p_area(y) p_dir(w) / |cos| of a photon that
// leaves light point y (the hit's light index + 1: light1; unit normal ng,
// outward for spheres) in direction w: what trace_photons stores with each
// photon, evaluated for a camera path that hit the light, so that both sides
// weigh a path that merging and path tracing can both make alike.
inline vreal light_photon_pdf(const Scene *sc, vreal light1, V3 y, V3 ng, V3 w, vmask two_sided, uint aim_mode)
{
    vreal p_area = (vreal)R(0);
    for (uint i = 0; i < NUM_LIGHTS; i++) {
        vmask is = light1 == (real)(i + 1);
        if (!VANY(is)) continue;
        real4 info = scene_rec(sc, OFF_LIGHTS + LIGHT_STRIDE * i + LIGHT_INFO);  // area, pick probability, ...
        p_area = VSEL(p_area, (vreal)(info.y / info.x), is);
    }
    vreal c = fabs(v3_dot(ng, w));
    vreal pf = p_area * aim_pdf(sc, y, ng, two_sided, aim_mode, w) / c;
    return VSEL(pf, (vreal)R(0), !(pf < R(INFINITY)));
}
