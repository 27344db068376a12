// photons.cl: trace_photons, the caustic photon pass.
//
// Each photon leaves a light (lights.h: picked by power, a point uniform by
// area) in a direction aimed at the caustic casters (photon_aim.h: purely
// specular objects, scene records after the lights: bounding sphere centre
// and radius, radius < 0 for an unbounded one). aim_mode 0 picks a caster in
// proportion to the solid angle of its bounding cone weighted by the largest
// cosine at the light inside it; aim_mode 1 picks casters equally, as in the
// paper. The direction is uniform in the chosen cone, and its pdf is the
// mixture over every cone that contains it, so the photons' flux stays
// unbiased either way:
//   flux = Le |cos| / (pdf_area pdf_sa) / n_emit.
// Photons follow mirror/refraction choices by Russian roulette over kr, kt
// and absorption (bsdf.h bsdf_sample, the lobes camera paths sample), and are
// stored at the first surface with a diffuse or Phong part after at least
// one specular bounce (L S+ D), then stop; a surface with a microfacet lobe
// (a rough conductor or dielectric) or a plastic ends them unstored, as
// camera paths do not merge there (scene.h material_mergeable). Random numbers: sampler.h.
//
// Launch: one work-item per CLPT_LANES photons (index gid * CLPT_LANES +
// lane); any local size. Photon i is written to slot i, stored or not
// (pos.w > 0 marks a stored one), so the result does not depend on timing.
// Buffers: scene, launch (clpt/layout.py PhotonLaunch) in; ph_pos (xyz,
// specular bounces), ph_dir (direction of travel, light-side pdf factor pf),
// ph_pow (flux) out; n_stored in/out (atomic).

#define PHOTON_MAX_BOUNCES 64

// The emission cosine of the photon's direction at the light, after what
// the light kinds without a surface change: a point or spot light has no
// cosine, and the spot's falloff in the direction taken scales its
// intensity (a textured spot's also its texture there, spot_texture_at); a
// directional light's or an environment's photon leaves its disk along its
// direction (lights.h), across it.
inline vreal photon_light_kinds(const Scene *sc, LightSample *lp, AimSample *aim)
{
    vreal cos_y = v3_dot(aim->w, lp->n);
#if CLPT_HAS_DELTA_LIGHTS
    cos_y = VSEL(cos_y, (vreal)R(1), lp->delta);
    lp->Le = v3_sel(lp->Le, v3_scale(lp->Le, delta_falloff(lp->n, lp->cos_cut, lp->cut, lp->inv_tr, lp->cos_beam,
                                                           aim->w)), lp->delta);
#endif
#if CLPT_HAS_TEXTURED_SPOTS
    for (int l = 0; l < CLPT_LANES; l++) {
        vreal st = lp->spot_tex, ex = lp->Le.x, ey = lp->Le.y, ez = lp->Le.z;
        vreal wx = aim->w.x, wy = aim->w.y, wz = aim->w.z;
        if (VLANE_R(st, l) == R(0) || !(VLANE_R(ex, l) + VLANE_R(ey, l) + VLANE_R(ez, l) > R(0)))
            continue;  // not a textured spot's photon, or outside its cone (falloff 0)
        real4 w = (real4)(VLANE_R(wx, l), VLANE_R(wy, l), VLANE_R(wz, l), R(0));
        real4 c = spot_texture_at(sc, (uint)VLANE_R(st, l), w);
        VLANE_R(lp->Le.x, l) = VLANE_R(ex, l) * c.x;
        VLANE_R(lp->Le.y, l) = VLANE_R(ey, l) * c.y;
        VLANE_R(lp->Le.z, l) = VLANE_R(ez, l) * c.z;
    }
#endif
#if CLPT_HAS_DIRECTIONAL_LIGHTS || CLPT_HAS_ENV_LIGHT
    cos_y = VSEL(cos_y, (vreal)R(1), lp->parallel);
    aim->w = v3_sel(aim->w, lp->n, lp->parallel);
    aim->pdf = VSEL(aim->pdf, (vreal)R(1), lp->parallel);
    aim->valid = aim->valid || lp->parallel;
#endif
    return cos_y;
}

__kernel void trace_photons(__global const real4 *scene, __constant PhotonLaunch *launch, __global float4 *ph_pos,
                            __global float4 *ph_dir, __global float4 *ph_pow, __global uint *n_stored)
{
    const PhotonLaunch L = *launch;
    Scene scd = scene_make(scene, L.scene);
    const Scene *sc = &scd;

    uint gid = get_global_id(0);
    uint first = gid * CLPT_LANES;
    vmask live = VREAL(VLANE_IDS) < (real)(first < L.n_emit ? min(L.n_emit - first, (uint)CLPT_LANES) : 0u);
    PhotonSampler sp = photon_sampler_make(L.seed, (vuint)first + VLANE_IDS);

    // --- emission ---------------------------------------------------------------
    EmitU ue = sample_photon_emission(&sp);
    LightSample lp;
    light_sample(sc, v3_zero(), ue.light, 0, live, &lp);
#if CLPT_HAS_ENV_LIGHT
    env_photon_start(sc, ue.u1, ue.u2, &lp);  // the aim's numbers: an environment's photon aims by its disk
#endif
    AimSample aim = aim_at_casters(sc, lp.p, lp.n, lp.two_sided, L.aim, ue.caster, ue.u1, ue.u2);
    vreal cos_y = photon_light_kinds(sc, &lp, &aim);
    vmask emits = cos_y > R(0) || (lp.two_sided && cos_y < R(0));
    live = live && aim.valid && emits && lp.pdf_area > R(0);
    // pf = p_area p_dir / |cos|, the light-side pdf factor of the photon's
    // multiple-importance weight (photon_aim.h); flux = Le / (pf n_emit).
    vreal pf = lp.pdf_area * aim.pdf / fabs(cos_y);
    vreal k = R(1) / (pf * (real)L.n_emit);
    V3 flux = v3_scale(lp.Le, VSEL((vreal)R(0), k, live));
    V3 o = offset_origin(sc, lp.p, v3_sel(v3_neg(lp.n), lp.n, cos_y > R(0)), lp.err);
#if CLPT_HAS_DELTA_LIGHTS
    // Path tracing cannot end a path on a delta light: a merge of its
    // photons takes the whole weight (pf = inf: the merge's pdf over the
    // BSDF's is infinite, path.h and photon_grid.h), and the photon leaves
    // the point itself.
    o = v3_sel(o, lp.p, lp.delta);
    pf = VSEL(pf, (vreal)R(INFINITY), lp.delta);
#endif
    V3 d = aim.w;

    // --- through specular surfaces to the first diffuse one ----------------------
    vmask stored = live && !live;
    V3 s_pos = v3_zero(), s_dir = v3_zero();
    vreal bounces = (vreal)R(0), s_bounces = (vreal)R(0);
    for (uint b = 0; b < PHOTON_MAX_BOUNCES && VANY(live); b++) {
        Hit h = scene_intersect(sc, o, d);
        live = live && h.t < R(INFINITY);
        Material m = material_fetch(sc, h.mat);
#if CLPT_HAS_TEXTURES
        material_textures(sc, &m, &h, live);
#endif
        V3 x = v3_fma(d, h.t, o);
        vmask front = v3_dot(h.ng, d) < R(0);
        live = live && (front || m.one_sided == R(0));  // a one-sided surface absorbs from behind
        vmask diffuse = live && m.nondelta != R(0);
        vmask store = diffuse && bounces > R(0) && material_mergeable(&m);
        s_pos = v3_sel(s_pos, x, store);
        s_dir = v3_sel(s_dir, d, store);
        s_bounces = VSEL(s_bounces, bounces, store);
        stored = stored || store;
        live = live && !diffuse;
        if (!VANY(live))
            break;
        V3 n = v3_sel(v3_neg(h.ng), h.ng, front);
        V3 ng_side = n;
        n = hit_shading_normal(sc, &h, ng_side);
#if CLPT_MITSUBA_SHADING
        live = live && !shading_from_behind(&m, &n, d, live && h.nrm >= R(0));
#endif
        // Russian roulette over the delta lobes, absorption always allowed;
        // flux, not radiance, crosses a refraction.
        BsdfSample bs;
        bsdf_sample(&m, lobe_probs(&m, live && !live), d, n, front, live, sample_photon_bounce(&sp, b),
                    TRANSPORT_IMPORTANCE, 0, &bs);
        live = live && bs.chosen;
        flux = v3_sel(flux, v3_mul(flux, bs.weight), live);
        o = v3_sel(o, offset_scattered(sc, x, v3_sel(v3_neg(n), n, bs.up), bs.wi, h.err), live);
        d = v3_sel(d, bs.wi, live);
        keep_geometric_side(sc, &o, &d, x, n, ng_side, live && h.nrm >= R(0), h.err);
        bounces = bounces + R(1);
    }

    stored = stored && v3_max_comp(flux) > R(0) && isfinite(flux.x + flux.y + flux.z);
    atomic_add(n_stored, vpopcount(stored));
    for (int l = 0; l < CLPT_LANES; l++) {
        uint i = first + l;
        if (i >= L.n_emit)
            break;
        int st = VLANE_M(stored, l) != 0;
        ph_pos[i] = (float4)(VLANE_R(s_pos.x, l), VLANE_R(s_pos.y, l), VLANE_R(s_pos.z, l),
                             st ? (float)VLANE_R(s_bounces, l) : 0.0f);
        ph_dir[i] = (float4)(VLANE_R(s_dir.x, l), VLANE_R(s_dir.y, l), VLANE_R(s_dir.z, l), (float)VLANE_R(pf, l));
        ph_pow[i] = st ? (float4)(VLANE_R(flux.x, l), VLANE_R(flux.y, l), VLANE_R(flux.z, l), 0.0f) : (float4)(0.0f);
    }
}
