// lights.h: next event estimation. Every emissive quad, triangle or sphere,
// and every emissive mesh as a whole, is an area light; one light is picked
// per lane by power from the alias table the host built (O(1) in the number
// of lights), then a point on it is drawn:
//   quad, triangle  uniformly by area (pdf_sa = dist^2 / (area |cos_l|))
//   mesh            a triangle by area from the mesh's alias table (O(1)),
//                   then uniformly on it: uniform over the mesh's whole area
//   sphere          uniformly in the cone it subtends (pdf_sa = 1 / (2 pi (1 - cos_max)))
//                   or, from inside it, uniformly by area.
// Emission leaves the side the normal points to, or both sides if two_sided.

typedef struct {
    V3 wi;        // unit direction from the shading point to the light point
    V3 p;         // the light point
    vreal dist;   // distance to the light point
    V3 Le;        // emitted radiance towards the shading point
    vreal pdf;    // solid-angle pdf of wi, times the pick probability
    vmask valid;  // a usable sample (emitting side faces the point, pdf > 0)
} LightSample;

// The light each lane picks, by power, in O(1): Walker's alias table (the
// host's pack.alias_table), slot j kept with probability info.z of light j
// and otherwise giving light n.w of light j's records. u_pick picks the
// slot and, rescaled, decides between the slot and its alias.
inline vreal light_pick_index(const Scene *sc, vreal u_pick)
{
    vreal li = (vreal)R(0);
    if (NUM_LIGHTS <= 1)
        return NUM_LIGHTS == 1 ? li : (vreal)R(INFINITY);
    for (int l = 0; l < CLPT_LANES; l++) {
        real u = VLANE_R(u_pick, l) * (real)NUM_LIGHTS;
        uint j = min((uint)u, (uint)NUM_LIGHTS - 1u);
        uint r = OFF_LIGHTS + LIGHT_STRIDE * j;
        real keep = scene_rec(sc, r + 4).z;
        VLANE_R(li, l) = u - (real)j < keep ? (real)j : scene_rec(sc, r + 3).w;
    }
    return li;
}

// The lights the lanes picked (li, +inf where done), one at a time: light
// *i, the lanes that picked it (pick) and its records at *r; the lanes are
// marked done in li. Returns 0 when none is left. Light-sampling costs so
// grow with the lights the lanes picked, at most CLPT_LANES, not with all
// of the scene's lights.
inline int light_next(const Scene *sc, vreal *li, uint *i, vmask *pick, uint *r)
{
    if (NUM_LIGHTS == 1) {  // one light: no search (a constant in specialized builds)
        *pick = *li == R(0);
        if (!VANY(*pick))
            return 0;
        *li = (vreal)R(INFINITY);
        *i = 0;
        *r = OFF_LIGHTS;
        return 1;
    }
    real m = vmin_lane(*li);
    if (!(m < R(INFINITY)))
        return 0;
    *i = (uint)m;
    *pick = *li == m;
    *li = VSEL(*li, (vreal)R(INFINITY), *pick);
    *r = OFF_LIGHTS + LIGHT_STRIDE * *i;
    return 1;
}

#if CLPT_HAS_MESH_LIGHTS
// A point y on the mesh light whose records start at r, and the normal n of
// its triangle (winding order), for the lanes in pick: the triangle by area
// from the mesh's alias table (LightTriRec), then a uniform point on it. u1
// picks the alias slot and, rescaled to [0, 1), serves again for the point.
inline void mesh_light_point(const Scene *sc, uint r, vmask pick, vreal u1, vreal u2, V3 *y, V3 *n)
{
    real4 mi = scene_rec(sc, r + 1);  // first triangle record, triangles
    uint base = (uint)mi.x, ntri = (uint)mi.y;
    V3 p = v3_zero(), eu = v3_zero(), ev = v3_zero();
    vreal ur = u1;
    for (int l = 0; l < CLPT_LANES; l++) {
        if (VLANE_M(pick, l) == 0)
            continue;
        real u = VLANE_R(u1, l) * (real)ntri;
        uint j = min((uint)u, ntri - 1u);
        real f = u - (real)j;
        real4 a = scene_rec(sc, base + LTRI_STRIDE * j), b = scene_rec(sc, base + LTRI_STRIDE * j + 1);
        if (f >= b.w) {
            f = (f - b.w) / (R(1) - b.w);
            j = (uint)a.w;
            a = scene_rec(sc, base + LTRI_STRIDE * j);
            b = scene_rec(sc, base + LTRI_STRIDE * j + 1);
        } else {
            f = f / b.w;
        }
        real4 c = scene_rec(sc, base + LTRI_STRIDE * j + 2);
        VLANE_R(ur, l) = fmin(fmax(f, R(0)), R(1) - REAL_EPS);
        VLANE_R(p.x, l) = a.x; VLANE_R(p.y, l) = a.y; VLANE_R(p.z, l) = a.z;
        VLANE_R(eu.x, l) = b.x; VLANE_R(eu.y, l) = b.y; VLANE_R(eu.z, l) = b.z;
        VLANE_R(ev.x, l) = c.x; VLANE_R(ev.y, l) = c.y; VLANE_R(ev.z, l) = c.z;
    }
    vreal a, b;
    sample_uniform_triangle(ur, u2, &a, &b);
    *y = v3_fma(ev, b, v3_fma(eu, a, p));
    *n = v3_normalize(v3_cross(eu, ev));
}
#endif

inline LightSample light_sample(const Scene *sc, V3 x, vreal u_pick, vreal u1, vreal u2)
{
    LightSample ls;
    ls.wi = ls.p = v3_zero();
    ls.Le = v3_zero();
    ls.dist = (vreal)R(0);
    ls.pdf = (vreal)R(0);
    ls.valid = (vreal)R(0) != (vreal)R(0);
    vreal li = light_pick_index(sc, u_pick);
    uint i, r;
    vmask pick;
    while (light_next(sc, &li, &i, &pick, &r)) {
        real4 info = scene_rec(sc, r + 4);  // area, pick probability, alias probability, material
        real4 p = scene_rec(sc, r);
        int kind = (int)p.w;
        V3 wi, Le;
        vreal dist, pdf_sa, cos_l;
        real4 m = scene_rec(sc, MAT_STRIDE * (uint)info.w + 4);  // Le.rgb, two_sided
        vmask emits;
#if CLPT_HAS_SPHERE_LIGHTS
        if (kind == LIGHT_KIND_SPHERE) {
            real rad = scene_rec(sc, r + 1).x;
            V3 dc = v3_sub(v3_splat(p), x);
            vreal d2 = v3_dot(dc, dc);
            // Cone sampling needs the point clearly outside; on or near the
            // surface (a sphere light lit by itself) area sampling is used.
            vmask outside = d2 > rad * rad * R(1.001);
            // Cone towards the centre; 1 - cos(theta_max) without cancellation.
            vreal sin2 = fmin(rad * rad / d2, R(1));
            vreal omc = sin2 / (R(1) + vsafe_sqrt(R(1) - sin2));
            V3 axis = v3_scale(dc, vrsqrt(d2));
            V3 lc = sample_uniform_cone(u1, u2, omc);
            V3 wc = frame_to_world(axis, lc.x, lc.y, lc.z);
            real4 sphere = (real4)(p.x, p.y, p.z, rad);
            vreal tc = intersect_sphere(sphere, x, wc);
            // Grazing cone-edge directions may round to a miss: take the tangent point.
            tc = VSEL(tc, v3_dot(dc, wc), isinf(tc));
            // From inside: a uniform point on the sphere, seen from within.
            V3 ls_dir = sample_uniform_sphere(u1, u2);
            V3 y = v3_fma(ls_dir, (vreal)rad, v3_splat(p));
            V3 wy = v3_sub(y, x);
            vreal dy2 = v3_dot(wy, wy);
            vreal dy = sqrt(dy2);
            wy = v3_scale(wy, R(1) / dy);
            vreal cos_in = -v3_dot(ls_dir, wy);  // < 0: the inside faces the point
            vreal area = info.x;
            wi = v3_sel(wy, wc, outside);
            dist = VSEL(dy, tc, outside);
            pdf_sa = VSEL(dy2 / (area * fabs(cos_in)), uniform_cone_pdf(omc), outside);
            cos_l = VSEL(cos_in, (vreal)R(1), outside);
        } else
#endif
        {
            V3 y, nl;
#if CLPT_HAS_MESH_LIGHTS
            if (kind == LIGHT_KIND_MESH) {
                mesh_light_point(sc, r, pick, u1, u2, &y, &nl);
            } else
#endif
            {
                real4 u = scene_rec(sc, r + 1), v = scene_rec(sc, r + 2), n = scene_rec(sc, r + 3);
                vreal a = u1, b = u2;
#if CLPT_HAS_TRIANGLE_LIGHTS
                if (kind == LIGHT_KIND_TRIANGLE)
                    sample_uniform_triangle(u1, u2, &a, &b);
#endif
                y = v3(p.x + a * u.x + b * v.x, p.y + a * u.y + b * v.y, p.z + a * u.z + b * v.z);
                nl = v3_splat(n);
            }
            V3 w = v3_sub(y, x);
            vreal d2 = v3_dot(w, w);
            dist = sqrt(d2);
            wi = v3_scale(w, R(1) / dist);
            cos_l = -v3_dot(wi, nl);
            pdf_sa = d2 / (info.x * fabs(cos_l));
        }
        emits = cos_l > R(0) || (m.w != R(0) && cos_l < R(0));
        Le = v3_splat(m);
        vmask ok = pick && emits && pdf_sa > R(0) && pdf_sa < R(INFINITY);
        ls.wi = v3_sel(ls.wi, wi, pick);
        ls.p = v3_sel(ls.p, v3_fma(wi, dist, x), pick);
        ls.dist = VSEL(ls.dist, dist, pick);
        ls.Le = v3_sel(ls.Le, Le, pick);
        ls.pdf = VSEL(ls.pdf, pdf_sa * info.y, pick);
        ls.valid = ls.valid || ok;
    }
    return ls;
}

// A point on a light for a photon to leave from: light picked by power, point
// uniform by area. pdf_area includes the pick probability.
typedef struct {
    V3 p, n;          // point and the light's normal there (outward for spheres)
    V3 Le;
    vmask two_sided;
    vreal pdf_area;
    vreal err;        // magnitude of the light's position and size (the point's rounding error follows it)
} LightPoint;

inline LightPoint light_sample_point(const Scene *sc, vreal u_pick, vreal u1, vreal u2)
{
    LightPoint lp;
    lp.p = lp.n = lp.Le = v3_zero();
    lp.pdf_area = lp.err = (vreal)R(0);
    lp.two_sided = lp.pdf_area != lp.pdf_area;
    vreal li = light_pick_index(sc, u_pick);
    uint i, r;
    vmask pick;
    while (light_next(sc, &li, &i, &pick, &r)) {
        real4 info = scene_rec(sc, r + 4);  // area, pick probability, alias probability, material
        real4 p = scene_rec(sc, r);
        int kind = (int)p.w;
        V3 y, n;
        vreal err;
#if CLPT_HAS_SPHERE_LIGHTS
        if (kind == LIGHT_KIND_SPHERE) {
            n = sample_uniform_sphere(u1, u2);
            y = v3_fma(n, (vreal)scene_rec(sc, r + 1).x, v3_splat(p));
            err = (vreal)(max_abs4(p) + scene_rec(sc, r + 1).x);
        } else
#endif
#if CLPT_HAS_MESH_LIGHTS
        if (kind == LIGHT_KIND_MESH) {
            mesh_light_point(sc, r, pick, u1, u2, &y, &n);
            err = fmax(fabs(y.x), fmax(fabs(y.y), fabs(y.z)));  // each lane's triangle: the point's magnitude
        } else
#endif
        {
            real4 u = scene_rec(sc, r + 1), v = scene_rec(sc, r + 2);
            err = (vreal)(max_abs4(p) + max_abs4(u) + max_abs4(v));
            vreal a = u1, b = u2;
#if CLPT_HAS_TRIANGLE_LIGHTS
            if (kind == LIGHT_KIND_TRIANGLE)
                sample_uniform_triangle(u1, u2, &a, &b);
#endif
            y = v3(p.x + a * u.x + b * v.x, p.y + a * u.y + b * v.y, p.z + a * u.z + b * v.z);
            n = v3_splat(scene_rec(sc, r + 3));
        }
        real4 m = scene_rec(sc, MAT_STRIDE * (uint)info.w + 4);  // Le.rgb, two_sided
        lp.p = v3_sel(lp.p, y, pick);
        lp.n = v3_sel(lp.n, n, pick);
        lp.Le = v3_sel(lp.Le, v3_splat(m), pick);
        lp.two_sided = lp.two_sided || (pick && (vreal)m.w != R(0));
        lp.pdf_area = VSEL(lp.pdf_area, (vreal)(info.y / info.x), pick);
        lp.err = VSEL(lp.err, err, pick);
    }
    return lp;
}

// Solid-angle pdf with which light_sample, called at x, draws the point y on
// the light it hits (light1: the hit's light index + 1; ng: the unit
// geometric normal at y; dist: |y - x|): the pick probability times the
// per-light pdf, for the multiple-importance weights of BSDF-sampled hits.
inline vreal light_pdf_hit(const Scene *sc, vreal light1, V3 x, V3 y, V3 ng, vreal dist)
{
    vreal pdf = (vreal)R(0);
    V3 w = v3_sub(y, x);
    vreal d2 = dist * dist;
    vreal li = VSEL(light1 - R(1), (vreal)R(INFINITY), light1 <= R(0));  // the lights hit, as light_next takes them
    uint i, r;
    vmask is;
    while (light_next(sc, &li, &i, &is, &r)) {
        real4 p = scene_rec(sc, r);
        real4 info = scene_rec(sc, r + 4);  // area, pick probability, alias probability, material
        vreal cos_l = fabs(v3_dot(ng, w)) / dist;
        vreal per = d2 / (info.x * cos_l);
#if CLPT_HAS_SPHERE_LIGHTS
        if ((int)p.w == LIGHT_KIND_SPHERE) {
            real rad = scene_rec(sc, r + 1).x;
            V3 dc = v3_sub(v3_splat(p), x);
            vreal dc2 = v3_dot(dc, dc);
            vreal sin2 = fmin(rad * rad / dc2, R(1));
            vreal omc = sin2 / (R(1) + vsafe_sqrt(R(1) - sin2));
            per = VSEL(per, uniform_cone_pdf(omc), dc2 > rad * rad * R(1.001));
        }
#endif
        pdf = VSEL(pdf, per * info.y, is);
    }
    return VSEL(pdf, (vreal)R(0), !(pdf < R(INFINITY)));
}
