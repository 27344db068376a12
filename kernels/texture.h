// texture.h: Mitsuba 3's bitmap and checkerboard textures, looked up at a
// hit's (u, v) (clpt/texture.py is the reference and says what each mode
// does). Compiled only when CLPT_HAS_TEXTURES: a scene without textures
// builds none of it.
//
// Records (clpt/layout.py): a material's coat_tab.z is its TEXTURE_SLOTS
// record (0: no textures), which holds the TEXTURE records of its
// reflectance (kd, or kp of a plastic), specular reflectance (km, gr of a
// rough dielectric, or kr), a rough conductor's alpha and transmittance (gt
// of a rough dielectric, or kt) (0 for none). A TEXTURE record points to its texels
// (3 reals each, row by row, from a record of its own, at the records' end:
// indexed as integers, past the 2^24 records float reals index) and to the
// UV section, one UV record per primitive id, from which hit_uv forms the
// hit's (u, v): a quad's or triangle's from the hit's edge coordinates
// (Hit.bu, .bv), a sphere's from its normal in the sphere's own frame.

#if CLPT_HAS_TEXTURES
#define TEX_PI R(3.14159265358979323846)
// clpt.scene.ALPHA_RANGE (tests/test_texture.py checks them): a textured alpha is clamped as a given one is.
#define TEX_ALPHA_MIN 1e-4
#define TEX_ALPHA_MAX 10.0

// Texel index i wrapped into [0, n) as the mode says (repeat, mirror, clamp).
inline int texture_wrap(int i, int n, int mode)
{
    if (mode == TEX_CLAMP)
        return clamp(i, 0, n - 1);
    int p = mode == TEX_MIRROR ? 2 * n : n;
    int k = i % p;
    k = k < 0 ? k + p : k;
    return k >= n ? p - 1 - k : k;
}

// floor(x) as an int, bounded (a NaN or huge coordinate gives a texel, never a wild index).
inline int texture_floor(real x)
{
    return (int)floor(fmin(fmax(x, R(-1e9)), R(1e9)));
}

inline real4 texture_texel(const Scene *sc, ulong first, int w, int i, int j)
{
    __global const real *t = (__global const real *)sc->rec + first + 3 * ((ulong)j * (ulong)w + (ulong)i);
    return (real4)(t[0], t[1], t[2], R(0));
}

// The RGB of the TEXTURE record at row r at surface coordinates (u, v).
inline real4 texture_eval(const Scene *sc, uint r, real u, real v)
{
    real4 ks = scene_rec(sc, r + TEX_KIND_SIZE), dt = scene_rec(sc, r + TEX_DATA);
    real4 mu = scene_rec(sc, r + TEX_UV_U), mv = scene_rec(sc, r + TEX_UV_V);
    real tu = mu.x * u + mu.y * v + mu.z, tv = mv.x * u + mv.y * v + mv.z;
    if ((int)ks.x == TEX_CHECKERBOARD) {
        int m0 = (tu - floor(tu) > R(0.5)) == (tv - floor(tv) > R(0.5));
        return scene_rec(sc, r + (m0 ? TEX_COLOR0 : TEX_COLOR1));
    }
    int w = (int)ks.y, h = (int)ks.z, wrap = (int)ks.w;
    ulong first = 4 * ((ulong)dt.x * TEX_ROW_SPLIT + (ulong)dt.y);
    if ((int)dt.z == TEX_NEAREST)
        return texture_texel(sc, first, w, texture_wrap(texture_floor(tu * w), w, wrap),
                             texture_wrap(texture_floor(tv * h), h, wrap));
    // Bilinear: the four texels whose centres surround the point.
    real x = tu * w - R(0.5), y = tv * h - R(0.5);
    int x0 = texture_floor(x), y0 = texture_floor(y);
    real fx = x - (real)x0, fy = y - (real)y0;
    int i0 = texture_wrap(x0, w, wrap), i1 = texture_wrap(x0 + 1, w, wrap);
    int j0 = texture_wrap(y0, h, wrap), j1 = texture_wrap(y0 + 1, h, wrap);
    return (R(1) - fy) * ((R(1) - fx) * texture_texel(sc, first, w, i0, j0) + fx * texture_texel(sc, first, w, i1, j0))
           + fy * ((R(1) - fx) * texture_texel(sc, first, w, i0, j1) + fx * texture_texel(sc, first, w, i1, j1));
}

// The (u, v) of primitive prim hit at edge coordinates (bu, bv) with unit
// geometric normal n (a sphere's: outward), from the UV section at uv_base.
inline real4 hit_uv(const Scene *sc, uint uv_base, real prim, real bu, real bv, real4 n)
{
    uint r = uv_base + UV_STRIDE * (uint)prim;
    real4 a = scene_rec(sc, r + UV_A), b = scene_rec(sc, r + UV_B);
    if ((int)b.w == UV_SPHERE) {
        real4 ez = a.w * cross(a, b);
        real lx = dot(a.xyz, n.xyz), ly = dot(b.xyz, n.xyz), lz = dot(ez.xyz, n.xyz);
        real phi = atan2(ly, lx);
        phi = phi < R(0) ? phi + R(2) * TEX_PI : phi;
        return (real4)(phi * R(0.5) / TEX_PI, acos(clamp(lz, R(-1), R(1))) / TEX_PI, R(0), R(0));
    }
    return (real4)(a.x + bu * a.z + bv * b.x, a.y + bu * a.w + bv * b.y, R(0), R(0));
}

#if CLPT_HAS_TEXTURED_EMITTERS
// A textured area light (Mitsuba 3's `area` emitter with a texture as its
// radiance; CLPT_HAS_TEXTURED_EMITTERS): its LIGHT_TEX row names the TEXTURE
// (0: none) and its primitive (a mesh light's first triangle). The radiance
// at a point is the texture at the point's (u, v), formed by hit_uv from
// the primitive's UV record (the UV section's row: the TEXTURE's data.w).
inline real4 emitter_texture(const Scene *sc, uint tex, real prim, real bu, real bv, real4 n)
{
    real4 uv = hit_uv(sc, (uint)scene_rec(sc, tex + TEX_DATA).w, prim, bu, bv, n);
    return texture_eval(sc, tex, uv.x, uv.y);
}

// The radiance of the textured lights the lanes in `hit` found at h, into m->Le.
inline void emitter_textures_hit(const Scene *sc, Material *m, const Hit *h, vmask hit)
{
    for (int l = 0; l < CLPT_LANES; l++) {
        vreal light = h->light;
        if (!VLANE_M(hit, l) || VLANE_R(light, l) <= R(0))
            continue;
        uint li = (uint)VLANE_R(light, l) - 1u;
        real4 t = scene_rec(sc, OFF_LIGHTS + LIGHT_STRIDE * li + LIGHT_TEX);
        if (t.x == R(0))
            continue;
        vreal prim = h->prim, bu = h->bu, bv = h->bv, nx = h->ng.x, ny = h->ng.y, nz = h->ng.z;
        real4 c = emitter_texture(sc, (uint)t.x, VLANE_R(prim, l), VLANE_R(bu, l), VLANE_R(bv, l),
                                  (real4)(VLANE_R(nx, l), VLANE_R(ny, l), VLANE_R(nz, l), R(0)));
        VLANE_R(m->Le.x, l) = c.x;
        VLANE_R(m->Le.y, l) = c.y;
        VLANE_R(m->Le.z, l) = c.z;
    }
}
#endif

// Scales lobe probability p by how much the textured colour c is of the
// bound b the host chose it for (so a lobe weight c / p stays what an
// untextured surface of colour c would have).
inline real texture_prob(real p, real4 c, real b)
{
    return b > R(0) ? p * fmax(c.x, fmax(c.y, c.z)) / b : p;
}

// Lane l of colour *k becomes the textured colour c; its lobe probability
// *p, where given, scaled by how much of the colour's bound c is (texture_prob).
inline void texture_colour(V3 *k, vreal *p, int l, real4 c)
{
    vreal kx = k->x, ky = k->y, kz = k->z;
    if (p) {
        vreal pl = *p;
        VLANE_R(*p, l) = texture_prob(VLANE_R(pl, l), c, fmax(VLANE_R(kx, l), fmax(VLANE_R(ky, l), VLANE_R(kz, l))));
    }
    VLANE_R(k->x, l) = c.x;
    VLANE_R(k->y, l) = c.y;
    VLANE_R(k->z, l) = c.z;
}

// The material m of the lanes in `hit` at their hits h, its textured values
// looked up there (a BSDF never knows whether a colour is constant). A rough
// dielectric's probability is the bound of its colours: it stays.
inline void material_textures(const Scene *sc, Material *m, const Hit *h, vmask hit)
{
    for (int l = 0; l < CLPT_LANES; l++) {
        if (!VLANE_M(hit, l))
            continue;
        vreal mat = h->mat;
        real ts = scene_rec(sc, MAT_STRIDE * (uint)VLANE_R(mat, l) + MAT_COAT_TAB).z;
        if (ts == R(0))
            continue;
        real4 slots = scene_rec(sc, (uint)ts + TEXS_SLOTS);
        real more = scene_rec(sc, (uint)ts + TEXS_MORE).x;
        vreal prim = h->prim, bu = h->bu, bv = h->bv;
        vreal nx = h->ng.x, ny = h->ng.y, nz = h->ng.z;
        real4 n = (real4)(VLANE_R(nx, l), VLANE_R(ny, l), VLANE_R(nz, l), R(0));
        real4 uv = hit_uv(sc, (uint)slots.w, VLANE_R(prim, l), VLANE_R(bu, l), VLANE_R(bv, l), n);
        vreal pp = (vreal)R(0), pm = m->p_m, pg = (vreal)R(0);
#if CLPT_HAS_PLASTIC
        pp = m->p_p;
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
        pg = m->p_g;
#endif
        int plastic = VLANE_R(pp, l) > R(0), conductor = VLANE_R(pm, l) > R(0), rough_glass = VLANE_R(pg, l) > R(0);
        if (slots.x > R(0)) {  // reflectance: a plastic's diffuse base, else the diffuse lobe
            real4 c = texture_eval(sc, (uint)slots.x, uv.x, uv.y);
#if CLPT_HAS_PLASTIC
            if (plastic)
                texture_colour(&m->kp, 0, l, c);
            else
#endif
                texture_colour(&m->kd, &m->p_d, l, c);
        }
        if (slots.y > R(0)) {  // specular reflectance: a rough dielectric's, a rough conductor's, else the mirror's
            real4 c = texture_eval(sc, (uint)slots.y, uv.x, uv.y);
#if CLPT_HAS_ROUGH_DIELECTRIC
            if (rough_glass)
                texture_colour(&m->gr, 0, l, c);
            else
#endif
            if (conductor)
                texture_colour(&m->km, &m->p_m, l, c);
            else
                texture_colour(&m->kr, &m->p_r, l, c);
        }
        if (more > R(0)) {  // transmittance: a rough dielectric's, else the smooth dielectric's
            real4 c = texture_eval(sc, (uint)more, uv.x, uv.y);
#if CLPT_HAS_ROUGH_DIELECTRIC
            if (rough_glass)
                texture_colour(&m->gt, 0, l, c);
            else
#endif
                texture_colour(&m->kt, &m->p_t, l, c);
        }
#if CLPT_HAS_MICROFACET
        if (slots.z > R(0)) {  // a rough conductor's alpha: the texture's luminance, within ALPHA_RANGE
            real4 c = texture_eval(sc, (uint)slots.z, uv.x, uv.y);
            real a = R(CLPT_LUMA_R) * c.x + R(CLPT_LUMA_G) * c.y + R(CLPT_LUMA_B) * c.z;
            VLANE_R(m->alpha, l) = clamp(a, R(TEX_ALPHA_MIN), R(TEX_ALPHA_MAX));
#if CLPT_HAS_ANISOTROPY
            VLANE_R(m->alpha_v, l) = VLANE_R(m->alpha, l);  // an alpha texture is isotropic
#endif
        }
#endif
    }
}

#endif
