// trace.cl: trace_paths, the path-tracing pass.
//
// Computes, for each pixel of a range, samples [sample_begin, sample_begin +
// n_samples) of the pixel's radiance estimate (path.h: the estimator and its
// events), and adds them one by one, in sample order, to the pixel's sums
// (film.h). The order of additions never depends on how samples are split
// into launches or on the work-group size, so an image is bit-identical
// however it was scheduled.
//
// Launch: one work-item per wi_entries (at most CLPT_LANES x LANE_PIXELS
// with lanes) consecutive pixels, or entries of an adaptive pass's list
// (film.h); global size = pixels (or entries) / wi_entries, in whole groups
// of any local size. Each lane
// starts a new path as soon as its previous one ends, and takes the
// work-item's next pixel as soon as it has finished its own, so lanes stay
// busy while paths have different lengths. Everything by value is in the launch record
// (clpt/layout.py TraceLaunch, read once into private memory).
//
// Buffers:
//   scene     in      packed scene records (scene.h)
//   launch    in      the TraceLaunch record
//   pix_sum   in/out  per pixel: sum r, sum g, sum b, sample count (film.h)
//   pix_sq    in/out  per pixel: sum of squared luminance
//   stats     out     per work-item: non-finite samples dropped, camera rays,
//                     bounce rays, shadow rays (this launch)
//   pix_jobs  in      adaptive passes: per entry (samples, max depth, first sample, pixel);
//                     in/out with pull_runs: the runs' counter after them (film.h)
//   aux       in/out  (CLPT_AUX) the feature sums, four planes (film.h VisibleSurface)
//   ph_pos, ph_dir, ph_pow, bucket_start, ph_occ  in  (CLPT_PHOTONS) the
//                     photon map and its grid (photon_grid.h)
//
// Flags: CLPT_LANES, CLPT_DOUBLE, CLPT_ACCUM_DOUBLE, CLPT_GENERIC, CLPT_NEE,
//   CLPT_PHOTONS, CLPT_AUX, CLPT_PIXEL_FILTER, CLPT_HAS_{SPHERES,QUADS,TRIANGLES,PLANES}, CLPT_HAS_{PHONG,MIRROR,GLASS},
//   CLPT_HAS_{TRIANGLE,SPHERE,MESH}_LIGHTS, CLPT_HAS_{BVH,SMOOTH}, CLPT_BVH_PACKETS, CLPT_NUM_* (when not generic).

#if CLPT_LANES > 1
// The lanes are explicit vectors already: a vector type hint tells Intel's
// CPU compiler not to vectorize the kernel once more across work-items. It
// did so to the photon kernel (16 x 16 wide, 128 gathers and 80 scatters)
// and ran it at a third of the speed; the plain kernel it left alone.
#define TRACE_PATHS_ATTRS __attribute__((vec_type_hint(vreal)))
#else
#define TRACE_PATHS_ATTRS
#endif

__kernel TRACE_PATHS_ATTRS void trace_paths(__global const real4 *scene, __constant TraceLaunch *launch,
                          __global pix_sum_t *pix_sum, __global pix_sq_t *pix_sq, __global uint4 *stats,
                          __global uint4 *pix_jobs
#if CLPT_AUX
                          , __global float4 *aux
#endif
#if CLPT_PHOTONS
                          , __global const float4 *ph_pos, __global const float4 *ph_dir,
                          __global const float4 *ph_pow, __global const uint *bucket_start, __global const uint *ph_occ
#endif
                          )
{
    const TraceLaunch L = *launch;
    Scene scd = scene_make(scene, L.scene);
    const Scene *sc = &scd;
    const PhotonLookup *pl = &L.photons;
#if CLPT_PHOTONS
    PhotonMap pmd;
    photon_map_init(&pmd, pl, ph_pos, ph_dir, ph_pow, bucket_start, ph_occ);
#endif
    uint gid = get_global_id(0);

    // --- the lanes' pixels, and their sums (taken as lanes finish theirs) ----------------------
#if CLPT_AUX
    __global float4 *aux_buf = aux;
#else
    __global float4 *aux_buf = 0;
#endif
    int aux_out = !pl->stop_at_x;  // the offline pre-pass's samples are not the image's features
    LaneJobs jobs = lane_jobs_none(gid, L.pull_runs ? L.wi_entries : 0u);
    Film film;
    film_zero(&film);
    VisibleSurface vis;
#if CLPT_AUX
    visible_zero(&vis);
#endif

    uint nonfinite = 0, n_camera = 0, n_bounce = 0, n_shadow = 0;
    vreal done_count = (vreal)R(0);  // samples of its pixel a lane has finished
    vmask active = lane_next(&jobs, &film, &vis, jobs.n == jobs.n, &L, pix_jobs, pix_sum, pix_sq, aux_buf,
                             aux_out);
    SamplerKeys keys = sampler_keys_make(L.seed, jobs.pixel);
    vmask restart = active;
    PathState ps = path_state_make(active);

    while (VANY(active)) {
        Sampler sp = sampler_make(L.seed, jobs.pixel, jobs.s_begin + VUINT(done_count), &keys);

        // --- start new paths in lanes whose previous path ended ----------------------------
        if (VANY(restart)) {
            vreal px = VREAL(jobs.pixel % L.width), py = VREAL(jobs.pixel / L.width);
#if CLPT_PIXEL_FILTER
            CameraU cu = camera_filter_sample(&L.pixel_filter, sample_camera(&sp), px, py, L.width, L.height);
#else
            CameraU cu = sample_camera(&sp);  // the box: a uniform point of the pixel
#endif
            path_start(&ps, &L.camera, px, py, cu, restart);
#if CLPT_AUX
            visible_start(&vis, restart);
#endif
            n_camera += vpopcount(restart);
        }

#if CLPT_HAS_ENV_LIGHT && CLPT_PREFETCH
        // What the vertex will read of a large environment map, fetched while the ray is traced:
        // next event estimation's texels, and those a ray that leaves the scene sees.
        if (env_prefetch_pays(sc)) {
#if CLPT_NEE
            LightU lu = sample_light(&sp, ps.depth);
            env_sample_prefetch(sc, active, lu.u1, lu.u2);
#endif
            env_eval_prefetch(sc, ps.d, active);
        }
#endif

        // --- closest hit ---------------------------------------------------------------------
        Vertex v = vertex_make(sc, &ps, scene_intersect_active(sc, ps.o, ps.d, active), active, L.rr_depth);
#if CLPT_AUX
        // The feature vertex, and whether this vertex is it or comes before it.
        vmask before_x = visible_add_vertex(&vis, v.hit, v.h.t, &v.m, v.n, ps.beta, v.front, L.aux_specular);
#endif

        // --- emission, weighted against light sampling and merging -------------------------
        vmask sees;
        V3 Le = path_emission(sc, pl, &ps, &v, &sees);
        if (L.hide_emitters != 0u)  // camera rays see no emission
            sees = sees && ps.depth > R(0);
#if CLPT_HAS_GLASS
        sees = sees && !ps.skip_le;  // taken whole at the glass vertex before (path_glass_split)
#endif
        ps.L = v3_sel(ps.L, v3_add(ps.L, Le), sees);
#if CLPT_AUX
        v3_add_where(&vis.emission, Le, sees && before_x);
#endif
        // A one-sided surface is black from behind.
        vmask go = v.hit && ps.depth < jobs.depth && (v.front || v.m.one_sided == R(0));
#if CLPT_HAS_GLASS
        n_bounce += path_glass_split(sc, pl, &ps, &v, go, &vis);
#endif

        // --- caustic photons: the gather at x, or merging ---------------------------------------
#if CLPT_PHOTONS
        path_photons(&pmd, pl, &ps, &v, &sp, jobs.depth, &go, &vis, L.lum_scale);
#endif

        // --- next event estimation -----------------------------------------------------------
#if CLPT_NEE
        vmask nee = go && v.m.nondelta != R(0);
#if CLPT_PHOTONS
        nee = nee && !pl->stop_at_x;
#endif
        n_shadow += path_direct_light(sc, &ps, &v, nee, &sp);
#endif

        // --- scattering ----------------------------------------------------------------------
        vmask cont = go;
        if (VANY(go)) {
            cont = path_scatter(sc, &ps, &v, go, sample_bsdf(&sp, ps.depth));
#if CLPT_PHOTONS
            path_class_update(&ps, &v, cont, pl->mis_k);
#endif
            n_bounce += vpopcount(cont);
        }

        // --- finished samples ----------------------------------------------------------------
        vmask done = active && !cont;
        if (VANY(done)) {
            film_add_sample(&film, done, ps.L, L.lum_scale, &nonfinite);
#if CLPT_AUX
            visible_end_sample(&vis, done);
#endif
            done_count = VSEL(done_count, done_count + R(1), done);
            restart = done && done_count < jobs.n;
            vmask ended = done && !restart;  // pixels finished: their lanes take the next ones
            if (VANY(ended)) {
                vmask more = lane_next(&jobs, &film, &vis, ended, &L, pix_jobs, pix_sum, pix_sq, aux_buf,
                                       aux_out);
                done_count = VSEL(done_count, (vreal)R(0), more);
                sampler_keys_take(&keys, L.seed, jobs.pixel, more);
                restart = restart || more;
            }
            active = (active && !done) || restart;
        } else {
            restart = active && !active;
        }
    }

    // (every lane's last pixel was stored when it ended: lane_next)
    stats[gid] = (uint4)(nonfinite, n_camera, n_bounce, n_shadow);
}
