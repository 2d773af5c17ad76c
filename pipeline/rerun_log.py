"""Log a run's internals to Rerun (rerun-sdk 0.41): one small interface, `log_run(result, rec)`.

The pipeline never calls this module: a run without a Rerun option pays nothing for it. It reads
a finished SetResult; candidate evidence comes from SetResult.explain (the matcher's own code).

Entity tree (stems are the photos' file stems):

    /params                               parameters (markdown, static)
    /log                                  warnings and progress (text log)
    /images/<stem>                        photo (JPEG in the recording)
    /images/<stem>/keypoints              SIFT keypoints
    /pairs/<ref>/<sup>/info               status, reason, inliers (markdown)
    /pairs/<ref>/<sup>/ref/...            in the reference: inliers, outliers, epipole, epilines (one
                                          fan, one batch), patches (sampled reference patches)
    /pairs/<ref>/<sup>/sup/...            in the support: inliers, outliers, epipole, epilines (the
                                          corresponding lines), candidates (coloured by HOG
                                          similarity), best (best candidates, labelled with scores)
    /pairs/<ref>/<sup>/mismatch           1 - P(x|I_sup) (Eq. 2), 8-bit heat map: blue = the support
                                          matches (static), red = no match, as in the inspector
    /pairs/<ref>/<sup>/mismatch_overlay   the same over the reference photo
    /pairs/<ref>/<sup>/no_evidence        where the support has no candidate (class 1)
    /dynamic/<ref>/prob                   P_dynamic, Eq. 3 (16-bit heat map)
    /dynamic/<ref>/mask                   mask at the threshold
    /dynamic/<ref>/overlay                heat map blended over the photo, mask outlined
    /dynamic/<ref>/gt                     ground truth (when the set has it; classes), gt_outline (its
                                          outline, green as in the inspector), jaccard (at the threshold
                                          and the best for the photo)
    /dynamic/<ref>/sweep                  P_dynamic after 1, 2, ... k supports (timeline "supports";
                                          for the first reference only when the preset sweeps depths:
                                          each step is a fusion of its own)
    /dynamic/<ref>/depth                  the depth all supports agreed on (sweep), near = bright
    /world/points                         the reconstruction's sparse points (3-D)
    /world/cameras/<stem>                 each registered camera: pose, pinhole and its photo
    /metrics/...                          timings and counts (scalars)

Timelines: "patch" steps through the sampled reference patches (each with its candidates), and
"supports" through the support sweep (the paper's Fig. 5).

Budget: candidates are logged for the first epipolar support of every reference (8 sampled
patches each), and for every epipolar support of the first reference; all pairs would multiply
the recording's size by the number of supports for little more to see.
"""

from __future__ import annotations

import json
import re

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .geometry import clip_lines

BLUEPRINT_ENTITY = "/meta/blueprint"


def part(stem: str) -> str:
    """A photo stem as one entity-path part."""
    return re.sub(r"[^A-Za-z0-9_\-]", "_", stem) or "_"


def _closed(quads: np.ndarray) -> np.ndarray:
    """(N, 4, 2) corners -> (N, 5, 2) closed strips, one batch."""
    return np.concatenate([quads, quads[:, :1]], axis=1)


def _heat(values: np.ndarray) -> np.ndarray:
    """(N,) in [0, 1] -> (N, 3) uint8 colours, blue (low) to red (high): OpenCV's 'turbo', the
    inspector's colour map."""
    import cv2
    v = np.clip(np.asarray(values) * 255, 0, 255).astype(np.uint8)[:, None]
    return cv2.applyColorMap(v, cv2.COLORMAP_TURBO)[:, 0, ::-1].copy()


# The inspector's colours (inspector/render.py; the pipeline does not import the UI)
HOG_RGB = (60, 220, 60)          # the best HOG (shape) candidate
COLOR_RGB = (255, 150, 20)       # the best colour candidate
REF_PATCH_RGB = (255, 255, 255)  # the reference patch
GT_RGB = (40, 255, 80)           # the ground truth's outline


def choose_focus(res) -> int:
    """The reference shown first: the photo with the most epipolar supports (they have lines and
    candidates to show), then the most supports."""
    def epipolar(i):
        return sum(res.pair_results[(i, j)].kind == "epipolar" for j in res.supports[i] if (i, j) in res.pair_results)
    return int(max(range(len(res.supports)), key=lambda i: (epipolar(i), len(res.supports[i]))))


def shown_supports(res, i: int) -> list[int]:
    """Photo i's supports, epipolar pairs first (the first screen shows the first one)."""
    kind = lambda j: res.pair_results[(i, j)].kind if (i, j) in res.pair_results else ""
    return sorted(res.supports[i], key=lambda j: (kind(j) != "epipolar", j))


def sample_pixels(res, i: int, n: int = 8) -> np.ndarray:
    """A useful sample of reference pixels: the strongest dynamic spots and spread static ones."""
    dyn = res.dynamic[i]
    h, w = dyn.shape
    import cv2
    peaks = dyn * (dyn >= cv2.dilate(dyn, np.ones((31, 31), np.uint8)))
    m = max(h, w) // 12                       # hot spots away from the borders
    peaks[:m], peaks[-m:], peaks[:, :m], peaks[:, -m:] = 0, 0, 0, 0
    order = np.argsort(peaks.ravel())[::-1][: n // 2]
    hot = np.column_stack([order % w, order // w]).astype(np.float64)
    gy, gx = np.mgrid[1:4, 1:4]
    spread = np.column_stack([gx.ravel() * w / 4, gy.ravel() * h / 4])[: n - len(hot)]
    return np.vstack([hot, spread])


def log_run(res, rec: rr.RecordingStream, focus: int | None = None, pixels: np.ndarray | None = None,
            gts: dict | None = None, threshold: float = 0.5) -> dict:
    """Log everything of a finished run. Returns the blueprint description (also logged).

    gts: ground truth per photo stem ((H, W) uint8 at the original size, 255 moving, 128 don't
    care); each photo that has it gets its outline and its Jaccard at `threshold` (the mask's)."""
    photos = res.photo_set.photos
    stems = [part(p.stem) for p in photos]
    focus = choose_focus(res) if focus is None else focus
    rec.log("/params", rr.TextDocument("```json\n" + json.dumps(res.params.to_dict(), indent=1) + "\n```",
                                       media_type=rr.MediaType.MARKDOWN), static=True)
    _at_start(rec)             # log rows on both timelines, so the log view shows them on either
    for msg in list(res.photo_set.warnings) + list(res.warnings):
        rec.log("/log", rr.TextLog(msg, level=rr.TextLogLevel.WARN))
    log_images(res, rec, stems)
    rec.log("/pairs", rr.AnnotationContext([(0, "evidence", (0, 0, 0, 0)), (1, "no evidence", (255, 0, 255, 120))]),
            static=True)
    for i, j in sorted(res.pairs):
        log_pair(res, rec, stems, i, j)
    scores = log_dynamic(res, rec, stems, gts or {}, threshold, focus)
    log_world(res, rec, stems)
    for i in range(len(photos)):
        if res.dynamic[i] is None:
            continue
        pts = sample_pixels(res, i) if (pixels is None or i != focus) else np.asarray(pixels, np.float64)
        epi = [j for j in shown_supports(res, i) if res.pair_results[(i, j)].kind == "epipolar"]
        for j in (epi if i == focus else epi[:1]):
            log_candidates(res, rec, stems, i, j, pts)
    log_metrics(res, rec)
    desc = {"focus": stems[focus], "supports": [stems[j] for j in shown_supports(res, focus)],
            "has_gt": bool(gts), "has_cameras": bool(res.cameras is not None and res.cameras.n_registered),
            "threshold": threshold, "jaccard": scores.get(focus)}
    rec.log(BLUEPRINT_ENTITY, rr.TextDocument(json.dumps(desc)), static=True)
    _at_start(rec)
    rec.log("/log", rr.TextLog(f"logged {len(photos)} photos, {len(res.pair_results)} pairs; "
                               f"first view: reference {photos[focus].stem}", level=rr.TextLogLevel.INFO))
    return desc


def _at_start(rec) -> None:
    rec.set_time("patch", sequence=0)
    rec.set_time("supports", sequence=0)


def log_images(res, rec, stems) -> None:
    for p, s, kp in zip(res.photo_set.photos, stems, res.keypoints or [None] * len(stems)):
        rec.log(f"/images/{s}", rr.Image(p.rgb).compress(jpeg_quality=85), static=True)
        if kp is not None and len(kp):
            rec.log(f"/images/{s}/keypoints", rr.Points2D(kp, radii=1.0, colors=[255, 255, 0]), static=True)


def log_pair(res, rec, stems, i: int, j: int) -> None:
    g = res.pairs[(i, j)]
    base = f"/pairs/{stems[i]}/{stems[j]}"
    unc = f", epipolar-line uncertainty {g.uncertainty_px:.1f} px" if np.isfinite(g.uncertainty_px) else ""
    rec.log(f"{base}/info", rr.TextDocument(
        f"**{res.photo_set.photos[i].stem} → {res.photo_set.photos[j].stem}**: {g.status}"
        f" (geometry: {g.source or 'rejected'}{unc})"
        f"{' — ' + g.reason if g.reason else ''}\n\n{g.n_matches} matches, {g.n_inliers} inliers, "
        f"spread {g.spread:.0%}, homography share {g.homography_share:.0%}",
        media_type=rr.MediaType.MARKDOWN), static=True)
    for side, inl, out in (("ref", g.inliers_ref, g.outliers_ref), ("sup", g.inliers_sup, g.outliers_sup)):
        if len(inl):
            rec.log(f"{base}/{side}/inliers", rr.Points2D(inl, radii=2.0, colors=[0, 220, 0]), static=True)
        if len(out):
            rec.log(f"{base}/{side}/outliers", rr.Points2D(out, radii=1.5, colors=[230, 40, 40]), static=True)
    r = res.pair_results.get((i, j))
    if r is None:
        return
    size_r, size_s = res.photo_set.photos[i].size, res.photo_set.photos[j].size
    if r.kind == "epipolar":
        from .geometry import epipoles
        e_r, e_s = epipoles(g.F)
        for side, e, size in (("ref", e_r, size_r), ("sup", e_s, size_s)):
            if abs(e[2]) > 1e-12:
                xy = e[:2] / e[2]
                if -0.5 <= xy[0] <= size[1] and -0.5 <= xy[1] <= size[0]:
                    rec.log(f"{base}/{side}/epipole", rr.Points2D([xy], radii=6.0, colors=[255, 0, 255],
                                                                  labels=["epipole"]), static=True)
        st, sg = r.strips, r.segments
        fan0 = np.nonzero(st.fan == 0)[0]
        # one boundary ray per strip of fan 0, from its first to its last sample: (S, 2, 2)
        th = st.theta_c[fan0] - 0.5 * st.dtheta
        d = np.stack([np.cos(th), np.sin(th)], axis=1)
        t0, t1 = st.t0[fan0], st.t0[fan0] + st.n_along[fan0]
        rays = np.stack([st.epipole + t0[:, None] * d, st.epipole + t1[:, None] * d], axis=1).astype(np.float32)
        if len(rays):
            rec.log(f"{base}/ref/epilines", rr.LineStrips2D(rays, radii=0.6, colors=[255, 220, 0]), static=True)
        seg, in_view = clip_lines(sg.bound_a[np.isin(sg.strip, fan0)], size_s)
        lines = seg[in_view]
        if len(lines):
            rec.log(f"{base}/sup/epilines", rr.LineStrips2D(lines, radii=0.6, colors=[255, 220, 0]), static=True)
    if r.kind == "peer":
        return
    # 1 - P: blue = matched (static), red = no match, the colours of the inspector and of P_dynamic
    miss = 1.0 - res.match_prob(i, j)
    rec.log(f"{base}/mismatch", rr.DepthImage(np.round(miss * 255).astype(np.uint8), meter=255.0,
                                              colormap="turbo", depth_range=(0.0, 255.0)), static=True)
    # where the support holds no candidate (out of its view): "no evidence", neutral in `default`
    rec.log(f"{base}/no_evidence", rr.SegmentationImage((r.evidence < 0.5).astype(np.uint8)), static=True)
    from .output import heat_overlay
    rec.log(f"{base}/mismatch_overlay",
            rr.Image(heat_overlay(res.photo_set.photos[i].rgb, miss)).compress(jpeg_quality=80), static=True)


def log_world(res, rec, stems) -> None:
    """The reconstruction in 3-D: sparse points and every registered camera with its photo."""
    cams = res.cameras
    if cams is None or not cams.n_registered:
        return
    rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if len(cams.points):
        # radii in screen points: the reconstruction's unit is arbitrary, so world radii were
        # invisible on one set and blobs on another
        rec.log("/world/points", rr.Points3D(cams.points, colors=cams.point_rgb, radii=rr.Radius.ui_points(2.0)),
                static=True)
    reg = np.nonzero(cams.registered)[0]
    centre = np.median(cams.points, axis=0) if len(cams.points) else cams.C[reg].mean(axis=0)
    # the photos at a tenth of the cameras' distance to the scene (a fixed 0.5 was lost in a
    # large reconstruction and hid a small one)
    plane = 0.1 * float(np.median(np.linalg.norm(cams.C[reg] - centre, axis=1))) or 0.5
    for k in np.nonzero(cams.registered)[0]:
        p = res.photo_set.photos[k]
        base = f"/world/cameras/{stems[k]}"
        rec.log(base, rr.Transform3D(translation=cams.C[k], mat3x3=cams.R[k].T), static=True)
        # our pixel convention puts (0, 0) at the first pixel's centre; Rerun's at its corner
        K = cams.K[k].copy()
        K[:2, 2] += 0.5
        rec.log(f"{base}/image", rr.Pinhole(image_from_camera=K, resolution=[p.size[1], p.size[0]],
                                            camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=plane),
                static=True)
        rec.log(f"{base}/image", rr.Image(p.rgb).compress(jpeg_quality=70), static=True)


def log_dynamic(res, rec, stems, gts: dict, threshold: float, focus: int | None = None) -> dict[int, str]:
    """P_dynamic of every photo with its mask, overlay, ground truth and Jaccard. Returns the
    Jaccard line per photo index that has ground truth."""
    from .evaluate import jaccard, jaccard_curve, THRESHOLDS
    from .output import to_original
    scores = {}
    rec.log("/dynamic", rr.AnnotationContext([(0, "static", (0, 0, 0, 0)), (1, "dynamic", (255, 255, 255, 140)),
                                              (2, "don't care", (80, 80, 255, 140))]), static=True)
    for i, (p, s) in enumerate(zip(res.photo_set.photos, stems)):
        dyn = res.dynamic[i]
        if dyn is None:
            continue
        base = f"/dynamic/{s}"
        rec.log(f"{base}/prob", rr.DepthImage(np.round(dyn * 65535).astype(np.uint16), meter=65535.0,
                                              colormap="turbo", depth_range=(0.0, 65535.0)), static=True)
        rec.log(f"{base}/mask", rr.SegmentationImage((dyn > threshold).astype(np.uint8)), static=True)
        from .output import heat_overlay
        rec.log(f"{base}/overlay", rr.Image(heat_overlay(p.rgb, dyn, dyn > threshold)).compress(jpeg_quality=85),
                static=True)
        if p.stem in gts:
            import cv2
            g = gts[p.stem]
            g = cv2.resize(g, (p.size[1], p.size[0]), interpolation=cv2.INTER_NEAREST)
            cls = np.where(g == 255, 1, np.where(g == 128, 2, 0)).astype(np.uint8)
            rec.log(f"{base}/gt", rr.SegmentationImage(cls), static=True)
            contours, _ = cv2.findContours((g == 255).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            # closed strips; +0.5: our pixel centres are at integers, Rerun's at half-integers
            strips = [np.vstack([c[:, 0], c[:1, 0]]).astype(np.float32) + 0.5 for c in contours if len(c) > 1]
            if strips:
                rec.log(f"{base}/gt_outline", rr.LineStrips2D(strips, colors=[GT_RGB], radii=rr.Radius.ui_points(1.5)),
                        static=True)
            # as `crowdcam eval` scores it: at the original size
            prob = to_original(dyn, p)
            curve = jaccard_curve(prob, gts[p.stem])
            k = int(np.argmax(curve))
            scores[i] = (f"Jaccard {jaccard(prob > threshold, gts[p.stem]):.2f} at the threshold {threshold:.2f} "
                         f"(best for this photo {curve[k]:.2f} at {THRESHOLDS[k]:.2f})")
            rec.log(f"{base}/jaccard", rr.TextDocument(scores[i]), static=True)
        f = res.fused(i, res.supports[i]) if res.params.sweep.enabled else None
        if f is not None:
            pair = next((res.pair_results[(i, j)].sweep for j in res.supports[i] if res.is_swept(i, j)
                         and res.pair_results[(i, j)].sweep.kind == "sweep"), None)
        if f is not None and pair is not None:
            gh, gw = f.plane.shape
            gy, gx = np.mgrid[0:gh, 0:gw]
            h, w = p.size                                    # grid pixel -> working pixel centres
            xy = np.column_stack([(gx.ravel() + 0.5) * w / gw - 0.5, (gy.ravel() + 0.5) * h / gh - 0.5])
            z = pair.depth_at(np.maximum(f.plane.ravel(), 0), xy, res.cameras.K[i]).reshape(gh, gw)
            inv = np.where((f.plane >= 0) & np.isfinite(z), 1.0 / np.maximum(z, 1e-9), 0.0)
            rec.log(f"{base}/depth", rr.DepthImage(np.round(inv / max(inv.max(), 1e-9) * 255).astype(np.uint8),
                                                   meter=255.0, colormap="viridis"), static=True)
        plane = res.plane_log_odds(i, res.supports[i])
        if plane is not None:
            # the plane-aligned difference's vote for "moving", as the map adds it: turbo, red = moving
            a = res.params.aggregate
            vote = -a.plane_weight * plane
            shown = np.clip(0.5 + vote / 8.0, 0.0, 1.0)
            rec.log(f"{base}/plane_cue", rr.DepthImage(np.round(shown * 255).astype(np.uint8), meter=255.0,
                                                       colormap="turbo", depth_range=(0.0, 255.0)), static=True)
        if res.params.sweep.enabled and i != focus:
            continue
        # the paper's Fig. 5: the map after 1, 2, ... k supports, made as the final map is
        for k, sweep in enumerate(res.sweep(i), start=1):
            # rows carry both timelines: on "patch" the sweep shows its last state, and vice versa
            rec.set_time("supports", sequence=k)
            rec.set_time("patch", sequence=0)
            rec.log(f"{base}/sweep", rr.DepthImage(np.round(sweep * 255).astype(np.uint8), meter=255.0,
                                                   colormap="turbo", depth_range=(0.0, 255.0)))
        rec.reset_time()
    return scores


def log_candidates(res, rec, stems, i: int, j: int, pixels: np.ndarray) -> None:
    """For each sampled pixel: the covering patch closest to it and all its candidates, on the
    "patch" timeline, so a user can follow one patch from strip to candidates to maps."""
    from .explain import patches_at
    r = res.pair_results[(i, j)]
    covering = patches_at(r, pixels)
    chosen = []
    for px, ids in zip(pixels, covering):
        if len(ids) == 0:
            continue
        from .patches import ref_patch_quads
        cen = ref_patch_quads(r.strips, r.patches.strip[ids], r.patches.start[ids]).mean(axis=1)
        chosen.append(int(ids[np.argmin(np.linalg.norm(cen - px, axis=1))]))
    if not chosen:
        return
    evidence = res.explain(i, j, patch_ids=np.array(chosen))
    base = f"/pairs/{stems[i]}/{stems[j]}"
    for k, ev in enumerate(evidence):
        rec.set_time("patch", sequence=k)
        rec.set_time("supports", sequence=0)
        rec.log(f"{base}/ref/patches", rr.LineStrips2D(_closed(ev.ref_quad[None]), radii=1.5, colors=[REF_PATCH_RGB],
                                                       labels=[f"patch {ev.patch}"]))
        if len(ev.sim_hog) == 0:
            rec.log(f"{base}/sup/candidates", rr.Clear(recursive=False))
            rec.log(f"{base}/sup/best", rr.Clear(recursive=False))
            continue
        # 1 - similarity: blue = alike (a match), red = unlike, as 1 - P(x|I_s) in the maps
        rec.log(f"{base}/sup/candidates", rr.LineStrips2D(_closed(ev.cand_quads), radii=0.4,
                                                          colors=_heat(1.0 - np.nan_to_num(ev.sim_hog))))
        best = [ev.best_hog, ev.best_color]
        labels = [f"best HOG {ev.sim_hog[ev.best_hog]:.2f} (colour {ev.sim_color[ev.best_hog]:.2f})",
                  f"best colour {ev.sim_color[ev.best_color]:.2f} (HOG {ev.sim_hog[ev.best_color]:.2f})"]
        rec.log(f"{base}/sup/best", rr.LineStrips2D(_closed(ev.cand_quads[best]), radii=2.0,
                                                    colors=[HOG_RGB, COLOR_RGB], labels=labels))
    rec.reset_time()


def log_metrics(res, rec) -> None:
    rec.log("/metrics/pair_seconds", rr.SeriesLines(names=["seconds per pair"]), static=True)
    for k, (_, r) in enumerate(sorted(res.pair_results.items())):
        rec.set_time("pair", sequence=k)
        rec.log("/metrics/pair_seconds", rr.Scalars(r.seconds))
    rec.log("/metrics/supports", rr.SeriesLines(names=["supports per photo"]), static=True)
    for i, s in enumerate(res.supports):
        rec.set_time("photo", sequence=i)
        rec.log("/metrics/supports", rr.Scalars(float(len(s))))
    rec.reset_time()
    rec.log("/metrics/timings", rr.TextDocument("\n".join(f"- {k}: {v:.2f}" for k, v in res.timings.items()),
                                                media_type=rr.MediaType.MARKDOWN), static=True)


def make_blueprint(desc: dict) -> rrb.Blueprint:
    """First screen: the reference with its overlays, a support with its corresponding lines,
    the aggregate over the photo (with the ground truth's outline and the Jaccard in its title),
    per-support maps, the sweep, the cameras in 3-D, and the log."""
    f = desc["focus"]
    sups = desc["supports"]
    s0 = sups[0] if sups else None
    top = [rrb.Spatial2DView(name=f"reference {f}", origin="/",
                             contents=[f"/images/{f}", f"/pairs/{f}/{s0}/ref/**"] if s0 else [f"/images/{f}"])]
    if s0:
        top.append(rrb.Spatial2DView(name=f"support {s0}", origin="/",
                                     contents=[f"/images/{s0}", f"/pairs/{f}/{s0}/sup/**"]))
    title = f"P_dynamic {f} (blue static, red moving" + ("; green: ground truth)" if desc.get("has_gt") else ")")
    if desc.get("jaccard"):
        title += f" · {desc['jaccard'].split(' (')[0]}"
    top.append(rrb.Spatial2DView(name=title, origin=f"/dynamic/{f}",
                                 contents=[f"/dynamic/{f}/overlay", f"/dynamic/{f}/gt_outline"]))
    # named by the support first: a narrow view keeps the start of its title
    maps = [rrb.Spatial2DView(name=f"{s}: 1 − P(x|I_s)", origin=f"/pairs/{f}/{s}",
                              contents=[f"/pairs/{f}/{s}/mismatch_overlay"]) for s in sups[:6]]
    bottom = [rrb.Grid(*maps, grid_columns=3, name="per-support maps")] if maps else []
    shares = [3.0] if maps else []
    bottom.append(rrb.Spatial2DView(name="support sweep (Fig. 5)", origin=f"/dynamic/{f}/sweep"))
    shares.append(2.0)
    if desc.get("has_cameras"):
        bottom.append(rrb.Spatial3DView(name="cameras and points", origin="/world"))
        shares.append(2.0)
    text = [rrb.TextLogView(origin="/log", name="log"),
            rrb.TextDocumentView(origin=f"/pairs/{f}/{s0}/info" if s0 else "/params", name="pair")]
    if desc.get("jaccard"):
        text.insert(0, rrb.TextDocumentView(origin=f"/dynamic/{f}/jaccard", name="Jaccard"))
    bottom.append(rrb.Vertical(*text))
    shares.append(2.0)
    return rrb.Blueprint(rrb.Vertical(rrb.Horizontal(*top), rrb.Horizontal(*bottom, column_shares=shares),
                                      row_shares=[3, 2]),
                         rrb.TimePanel(timeline="patch", play_state="paused"), collapse_panels=True)


def read_blueprint_desc(path) -> dict:
    """The blueprint description stored in a recording (for `crowdcam view`)."""
    from rerun.chunk import RrdReader
    store = RrdReader(str(path)).store()
    for ch in store.stream().filter(content=BLUEPRINT_ENTITY).to_chunks():
        return json.loads(ch.to_record_batch().column("TextDocument:text")[0].as_py()[0])
    raise ValueError(f"{path}: not a crowdcam recording (no {BLUEPRINT_ENTITY})")
