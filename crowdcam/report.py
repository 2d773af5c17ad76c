"""`crowdcam report SET --out DIR`: the failure gallery of a set as a report to attach to a bug.

Runs the detection (from the pair cache when `crowdcam detect` ran before with the same preset
and size), builds each reference's gallery (pipeline/gallery.py) and writes, into a staging
folder renamed into place when complete:

    report.md, report.html    the same content; the HTML is self-contained apart from img/
    report.json               the galleries as data (regions, diagnoses, figures)
    img/<stem>_map.jpg        P_dynamic over the photo, mask outlined, regions numbered
    img/<stem>_gt.png         mask against ground truth (found, missed, lit up, don't care)
    img/<stem>_<kind><rank>.png  per region: photo crop and map crop, region outlined, its pixel marked
"""

from __future__ import annotations

import html
import json
import os
import shlex
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from pipeline.gallery import (CUE_INTRO, CUE_TITLE, CUES, FALSE_ALARM, KIND_TITLE, MISSED, UNCERTAIN, Gallery,
                              GalleryEntry, build_gallery, cue_summary, gt_at, signed)
from pipeline.params import DEFAULT_MAX_SIDE

# colours (RGB) of the pictures, one language with the inspector: turbo-like heat, white mask outline
C_MISSED = (255, 0, 255)        # magenta: moving, not found
C_FALSE = (255, 140, 0)         # orange: static, lit up
C_UNCERTAIN = (0, 255, 255)     # cyan: undecided
C_FOUND = (40, 200, 60)         # green: moving and found
KIND_COLOUR = {MISSED: C_MISSED, FALSE_ALARM: C_FALSE, UNCERTAIN: C_UNCERTAIN}
KIND_LETTER = {MISSED: "M", FALSE_ALARM: "F", UNCERTAIN: "U"}
KIND_PLURAL = {MISSED: "missed movers", FALSE_ALARM: "static regions lit up", UNCERTAIN: "uncertain regions"}


# ----------------------------------------------------------------------------- pictures
def heat(rgb: np.ndarray, prob: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """(h, w, 3) uint8 RGB: blue (static) to red (dynamic) over the photo (as the detect overlays)."""
    from pipeline.output import heat_overlay
    return heat_overlay(rgb, prob, None, alpha)


def _outline(img: np.ndarray, mask: np.ndarray, colour, thickness: int = 1, offset=(0, 0)) -> None:
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=offset)
    cv2.drawContours(img, contours, -1, colour, thickness, lineType=cv2.LINE_AA)


def map_picture(rgb: np.ndarray, prob: np.ndarray, threshold: float, gallery: Gallery) -> np.ndarray:
    """The reference's map with the mask outlined (white) and the gallery's regions boxed and
    labelled (M1, F2, U3 in their kind's colour); (h, w, 3) uint8 RGB, scaled up to >= 640 px."""
    img = heat(rgb, prob)
    _outline(img, prob > threshold, (255, 255, 255))
    f = max(1, int(np.ceil(640 / max(img.shape[:2]))))
    img = cv2.resize(img, (img.shape[1] * f, img.shape[0] * f), interpolation=cv2.INTER_NEAREST)
    for e in gallery.entries:
        r = e.region
        c = KIND_COLOUR[r.kind]
        x0, y0, x1, y1 = (v * f for v in r.bbox)
        cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), c, 2)
        label = f"{KIND_LETTER[r.kind]}{r.rank}"
        ty = y0 - 4 if y0 > 16 else y1 + 14
        cv2.putText(img, label, (x0, ty), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, (x0, ty), cv2.FONT_HERSHEY_SIMPLEX, 0.5, c, 1, cv2.LINE_AA)
    return img


def truth_picture(rgb: np.ndarray, prob: np.ndarray, threshold: float, gt: np.ndarray) -> np.ndarray:
    """Mask against ground truth over a dimmed photo: found movers green, missed magenta, lit-up
    static orange, don't care grey; (h, w, 3) uint8 RGB, scaled up like map_picture."""
    pred = prob > threshold
    moving, dc = gt == 255, gt == 128
    img = (rgb.astype(np.float32) * 0.45).astype(np.uint8)
    for m, c in ((dc, (128, 128, 128)), (moving & pred, C_FOUND), (moving & ~pred, C_MISSED),
                 (pred & ~moving & ~dc, C_FALSE)):
        img[m] = (0.35 * img[m] + 0.65 * np.array(c)).astype(np.uint8)
    f = max(1, int(np.ceil(640 / max(img.shape[:2]))))
    return cv2.resize(img, (img.shape[1] * f, img.shape[0] * f), interpolation=cv2.INTER_NEAREST)


def crop_picture(rgb: np.ndarray, prob: np.ndarray, threshold: float, entry: GalleryEntry, pad: int,
                 side: int = 260) -> np.ndarray:
    """Photo crop and map crop side by side around the region (padded by `pad` px), the region
    outlined in its kind's colour, the mask in white on the map, the region's pixel marked with a
    cross; each panel scaled to `side` px on its longer side. (side', 2 side' + gap, 3) uint8 RGB."""
    r = entry.region
    h, w = prob.shape
    x0, y0, x1, y1 = r.bbox
    cx0, cy0 = max(0, x0 - pad), max(0, y0 - pad)
    cx1, cy1 = min(w, x1 + pad), min(h, y1 + pad)
    f = side / max(cx1 - cx0, cy1 - cy0)
    size = (max(1, round((cx1 - cx0) * f)), max(1, round((cy1 - cy0) * f)))
    photo = cv2.resize(rgb[cy0:cy1, cx0:cx1], size, interpolation=cv2.INTER_CUBIC if f > 1 else cv2.INTER_AREA)
    pm = prob[cy0:cy1, cx0:cx1]
    hm = cv2.resize(heat(rgb[cy0:cy1, cx0:cx1], pm, 0.6), size, interpolation=cv2.INTER_NEAREST)
    region = cv2.resize(r.full_mask((h, w))[cy0:cy1, cx0:cx1].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    mask = cv2.resize((pm > threshold).astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    c = KIND_COLOUR[r.kind]
    _outline(hm, mask, (255, 255, 255), 1)
    px, py = round((r.pixel[0] - cx0 + 0.5) * f - 0.5), round((r.pixel[1] - cy0 + 0.5) * f - 0.5)
    for img in (photo, hm):
        _outline(img, region, (0, 0, 0), 4)
        _outline(img, region, c, 2)
        cv2.drawMarker(img, (px, py), (0, 0, 0), cv2.MARKER_CROSS, 16, 4)
        cv2.drawMarker(img, (px, py), (255, 255, 255), cv2.MARKER_CROSS, 16, 2)
    gap = np.full((size[1], 6, 3), 255, np.uint8)
    return np.concatenate([photo, gap, hm], axis=1)


def _write_image(path: Path, rgb: np.ndarray) -> None:
    params = [cv2.IMWRITE_JPEG_QUALITY, 85] if path.suffix == ".jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 6]
    ok, buf = cv2.imencode(path.suffix, rgb[..., ::-1], params)
    if not ok:
        raise OSError(f"could not encode {path}")
    path.write_bytes(buf.tobytes())


# ----------------------------------------------------------------------------- text
def _safe(stem: str) -> str:
    """A file-name-safe form of a photo stem (for img/)."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in stem)


def explain_commands(set_arg: str, stem: str, xy: tuple[int, int], max_side: int, preset: str,
                     changes: tuple[str, ...] = ()) -> list[str]:
    """Shell commands that explain a pixel: the inspector (pick the reference, click the pixel)
    and a Rerun recording of that pixel's evidence (crowdcam detect --rr-ref --rr-pixel), with the
    run's --param changes, so that they show the same maps."""
    opts = []
    if max_side != DEFAULT_MAX_SIDE:
        opts += ["--max-side", str(max_side)]
    if preset != "default":
        opts += ["--preset", preset]
    for c in changes:
        opts += ["--param", c]
    q = shlex.quote
    base = " ".join([q(set_arg)] + [q(o) for o in opts])
    return [f"crowdcam inspect {base}   # Reference {stem}, click pixel ({xy[0]}, {xy[1]})",
            f"crowdcam detect {base} --rr-ref {q(stem)} --rr-pixel {xy[0]},{xy[1]} --rrd {q(_safe(stem))}.rrd "
            f"&& crowdcam view {q(_safe(stem))}.rrd"]


def _support_table_md(entry: GalleryEntry) -> list[str]:
    rows = ["| support | sees it | P(x\\|I_s) | HOG | colour | at agreed depth | lines ± px | geometry | vote |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for f in entry.support_figures:
        v = lambda k: "–" if f[k] is None else f"{f[k]}"
        rows.append(f"| {f['support']} | {'yes' if f['sees'] else 'no'} ({f['evidence']:.2f}) | {v('p')} | {v('hog')} | "
                    f"{v('colour')} | {v('depth')} | {v('uncertainty_px')} | {f['source']} | {f['vote']} |")
    return rows


def _entry_heading(e: GalleryEntry, scale: float) -> str:
    r = e.region
    orig = r.area / (scale * scale)
    s = (f"{KIND_LETTER[r.kind]}{r.rank} · {KIND_TITLE[r.kind]} · {r.area} px ({r.share:.2%} of the photo, "
         f"≈{orig:,.0f} px at full size) · mean P {r.mean_p:.2f}")
    if r.kind == MISSED and r.object_area:
        s += f" · part of a mover of {r.object_area} px, {r.object_found:.0%} of it found"
    return s


# ----------------------------------------------------------------------------- the report
def write_report(res, galleries: dict[int, Gallery], gts: dict, out: Path, set_arg: str, threshold: float,
                 seconds: dict, scores: dict, changes: tuple[str, ...] = ()) -> Path:
    """Write report.md, report.html, report.json and img/ into a staging folder beside `out` and
    rename it into place (a previous report is replaced only when the new one is complete).
    changes: the run's `--param` settings (named in the report and in its commands)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        _write_into(stage, res, galleries, gts, set_arg, threshold, seconds, scores, changes)
        if out.exists():
            trash = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.replace(out, trash / "old")
            os.replace(stage, out)
            shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return out


def _write_into(stage: Path, res, galleries, gts, set_arg, threshold, seconds, scores, changes=()) -> None:
    from pipeline.evaluate import THRESHOLDS, jaccard_curve
    from pipeline.output import to_original
    ps, p = res.photo_set, res.params
    best = {}                        # per photo with ground truth: (best threshold, its Jaccard)
    for i in galleries:
        stem = ps.photos[i].stem
        if stem in gts:
            curve = jaccard_curve(to_original(res.dynamic[i], ps.photos[i]), gts[stem])
            k = int(np.argmax(curve))
            best[stem] = (float(THRESHOLDS[k]), float(curve[k]))
    (stage / "img").mkdir()
    from pipeline.matching import patch_length
    pad = 2 * patch_length(p)
    md: list[str] = []
    body: list[str] = []
    data = {"set": ps.name, "input": str(Path(ps.root).resolve()), "preset": p.preset, "max_side": p.max_side,
            "changes": list(changes), "threshold": threshold, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "seconds": seconds, "references": []}
    has_gt = any(g.has_gt for g in galleries.values())
    title = f"Failure gallery: {ps.name}"
    changed = f" with {', '.join(f'`{c}`' for c in changes)}" if changes else ""
    intro = (f"Set `{ps.root}`, {len(ps.photos)} photos, preset `{p.preset}`{changed}, working size {p.max_side} px, "
             f"threshold {threshold:g}. " +
             ("Per photo, the missed movers (M, magenta: moving in the ground truth, not in the mask) and the "
              "static regions lit up (F, orange: in the mask, static in the ground truth), ranked by area, each with a "
              "first diagnosis from the evidence the pipeline computed." if has_gt else
              "No ground truth: per photo, the most uncertain regions (U, cyan: P_dynamic near the threshold, or "
              "supports that disagree), ranked by their summed uncertainty, each with a first diagnosis.") +
             f" Pixel coordinates are at the working size ({p.max_side} px on the longer side). "
             f"Detection and diagnosis took {seconds.get('total_s', 0):.1f} s ({seconds.get('gallery_s', 0):.1f} s of "
             "it the diagnosis).")
    md += [f"# {title}", "", intro, ""]
    body += [f"<h1>{html.escape(title)}</h1>", f"<p>{_md_inline_to_html(intro)}</p>"]

    # tally of headline causes over the set
    tally: dict[str, int] = {}
    for g in galleries.values():
        for e in g.entries:
            tally[e.headline.title] = tally.get(e.headline.title, 0) + 1
    if tally:
        line = "Headline causes over the set: " + ", ".join(f"{k} ({v})" for k, v in
                                                             sorted(tally.items(), key=lambda kv: -kv[1])) + "."
        md += [line, ""]
        body.append(f"<p>{html.escape(line)}</p>")
    # overview table
    head = ["photo", "supports", "Jaccard at threshold", "best threshold (Jaccard)", "missed movers",
            "static lit up"] if has_gt else \
        ["photo", "supports", "uncertain regions"]
    md += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    trs = []
    for i, g in galleries.items():
        stem = ps.photos[i].stem
        cells = [f"[{stem}](#{_anchor(stem)})", str(len(res.supports[i]))]
        if has_gt:
            j = scores.get(stem)
            b = best.get(stem)
            cells += ["–" if j is None else f"{j:.2f}", "–" if b is None else f"{b[0]:.3f} ({b[1]:.2f})",
                      str(g.counts.get(MISSED, 0)), str(g.counts.get(FALSE_ALARM, 0))]
        else:
            cells += [str(g.counts.get(UNCERTAIN, 0))]
        md.append("| " + " | ".join(cells) + " |")
        trs.append("<tr>" + "".join(f"<td>{_md_inline_to_html(c)}</td>" for c in cells) + "</tr>")
    body.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" + "".join(trs) +
                "</table>")
    cue_rows = [c for i in galleries if ps.photos[i].stem in gts
                and (c := cue_summary(res, i, gts[ps.photos[i].stem])) is not None]
    if cue_rows:
        md_c, html_c = _cue_table(cue_rows)
        md += [""] + md_c
        body += html_c
        data["cues"] = [c.to_dict() for c in cue_rows]
    skipped = [ph.stem for k, ph in enumerate(ps.photos) if k not in galleries]
    if skipped:
        line = f"No map (no usable support): {', '.join(skipped)}."
        md += ["", line]
        body.append(f"<p>{html.escape(line)}</p>")
    md.append("")

    for i, g in galleries.items():
        photo = ps.photos[i]
        stem, safe = photo.stem, _safe(photo.stem)
        prob = res.dynamic[i]
        rgb = photo.rgb
        gt = gt_at(gts[stem], photo.size) if stem in gts else None
        _write_image(stage / "img" / f"{safe}_map.jpg", map_picture(rgb, prob, threshold, g))
        pics = [(f"img/{safe}_map.jpg", "P_dynamic (blue static, red dynamic), mask outlined in white, regions boxed")]
        if gt is not None:
            _write_image(stage / "img" / f"{safe}_gt.png", truth_picture(rgb, prob, threshold, gt))
            pics.append((f"img/{safe}_gt.png", "mask against ground truth: found green, missed magenta, "
                                               "lit up orange, don't care grey"))
        sj = scores.get(stem)
        h2 = f"{stem}" + (f" · Jaccard {sj:.2f}" if sj is not None else "")
        sup_line = f"Supports: {', '.join(ps.photos[j].stem for j in res.supports[i])}."
        counts = ", ".join(f"{v} {KIND_TITLE[k] if v == 1 else KIND_PLURAL[k]}" for k, v in g.counts.items()) or "none"
        md += [f"## {h2}", "", f"{sup_line} Regions found: {counts}.", ""]
        md += [f"![{alt}]({src})" for src, alt in pics] + [""]
        body += [f'<h2 id="{_anchor(stem)}">{html.escape(h2)}</h2>',
                 f"<p>{html.escape(sup_line)} Regions found: {html.escape(counts)}.</p>",
                 '<div class="pics">' + "".join(f'<figure><img src="{html.escape(src)}" alt="{html.escape(alt)}">'
                                                f"<figcaption>{html.escape(alt)}</figcaption></figure>"
                                                for src, alt in pics) + "</div>"]
        if not g.entries:
            md += ["Nothing to show: no region above the minimum size.", ""]
            body.append("<p>Nothing to show: no region above the minimum size.</p>")
        ref_data = {"stem": stem, "supports": [ps.photos[j].stem for j in res.supports[i]], "jaccard": sj,
                    "counts": g.counts, "entries": []}
        for e in g.entries:
            r = e.region
            name = f"{safe}_{r.kind}{r.rank}.png"
            _write_image(stage / "img" / name, crop_picture(rgb, prob, threshold, e, pad))
            head3 = _entry_heading(e, photo.scale)
            cmds = explain_commands(set_arg, stem, r.pixel, p.max_side, p.preset, changes)
            full = (round((r.pixel[0] + 0.5) / photo.scale - 0.5), round((r.pixel[1] + 0.5) / photo.scale - 0.5))
            where = (f"Pixel ({r.pixel[0]}, {r.pixel[1]}) at the working size, ({full[0]}, {full[1]}) in the original "
                     f"photo; box {r.bbox[0]},{r.bbox[1]}–{r.bbox[2]},{r.bbox[3]}.")
            md += [f"### {head3}", "", f"![{KIND_TITLE[r.kind]} {r.rank}: photo and map, region outlined](img/{name})",
                   "", f"**{e.headline.title}**: {e.headline.detail}.", ""]
            md += [f"- also: *{d.title}*: {d.detail}." for d in e.diagnoses[1:]]
            md += ["", where, "", "```", *cmds, "```", "", *_support_table_md(e), ""]
            body += [f'<section class="entry {r.kind}"><h3>{html.escape(head3)}</h3>',
                     f'<img src="img/{html.escape(name)}" alt="{html.escape(KIND_TITLE[r.kind])} {r.rank}">',
                     f"<p><b>{html.escape(e.headline.title)}</b>: {html.escape(e.headline.detail)}.</p>"]
            if len(e.diagnoses) > 1:
                body.append("<ul>" + "".join(f"<li>also: <i>{html.escape(d.title)}</i>: {html.escape(d.detail)}.</li>"
                                             for d in e.diagnoses[1:]) + "</ul>")
            body += [f"<p>{html.escape(where)}</p>", "<pre>" + html.escape("\n".join(cmds)) + "</pre>",
                     _support_table_html(e), "</section>"]
            ref_data["entries"].append({
                "kind": r.kind, "rank": r.rank, "area_px": r.area, "share": round(r.share, 5), "bbox": list(r.bbox),
                "pixel": list(r.pixel), "pixel_original": list(full), "mean_p": round(r.mean_p, 3),
                "object_area_px": r.object_area, "object_found": None if not np.isfinite(r.object_found)
                else round(r.object_found, 3), "image": f"img/{name}",
                "diagnoses": [{"code": d.code, "title": d.title, "detail": d.detail, "strength": round(d.strength, 2),
                               "figures": d.figures} for d in e.diagnoses],
                "supports": list(e.support_figures), "commands": cmds})
        data["references"].append(ref_data)
    (stage / "report.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    (stage / "report.html").write_text(_html_page(title, "\n".join(body)), encoding="utf-8")
    (stage / "report.json").write_text(json.dumps(data, indent=1, default=_json_default), encoding="utf-8")


def _cue_table(rows) -> tuple[list[str], list[str]]:
    """The cues' table (pipeline.gallery.cue_summary per photo) as markdown lines and HTML parts."""
    head = ["photo"] + [f"{CUE_TITLE[c]}: moving / static" for c in CUES] + ["P_dynamic: moving / static"]
    cells = [[r.stem] + [f"{signed(r.moving[c])} / {signed(r.static[c])}" for c in CUES] +
             ["{:.2f} / {:.3f}".format(*r.dynamic)] for r in rows]
    intro = f"What each cue says: {CUE_INTRO}"
    md = [intro, "", "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)] + \
        ["| " + " | ".join(c) + " |" for c in cells]
    page = [f"<p>{html.escape(intro)}</p>",
            "<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" +
            "".join("<tr>" + "".join(f"<td>{html.escape(x)}</td>" for x in c) + "</tr>" for c in cells) + "</table>"]
    return md, page


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o).__name__)


def _anchor(stem: str) -> str:
    return "ref-" + _safe(stem).lower()


def _md_inline_to_html(s: str) -> str:
    """The little Markdown the report's cells use: `code` and [text](#anchor)."""
    import re
    s = html.escape(s)
    s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
    return re.sub(r"\[([^\]]+)\]\((#[^)]+)\)", r'<a href="\2">\1</a>', s)


def _support_table_html(e: GalleryEntry) -> str:
    head = ["support", "sees it", "P(x|I_s)", "HOG", "colour", "at agreed depth", "lines ± px", "geometry", "vote"]
    rows = []
    for f in e.support_figures:
        v = lambda k: "–" if f[k] is None else f"{f[k]}"
        cells = [f["support"], f"{'yes' if f['sees'] else 'no'} ({f['evidence']:.2f})", v("p"), v("hog"), v("colour"),
                 v("depth"), v("uncertainty_px"), f["source"], f["vote"]]
        rows.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    return ('<table class="sup"><tr>' + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" + "".join(rows)
            + "</table>")


def _html_page(title: str, body: str) -> str:
    css = """
body{font:15px/1.45 system-ui,-apple-system,'Segoe UI',sans-serif;color:#1d2330;max-width:1100px;margin:2em auto;padding:0 1em}
h1{font-size:1.6em}h2{margin-top:2em;border-bottom:1px solid #ccd}h3{font-size:1.05em;margin:0 0 .4em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccd;padding:2px 8px;text-align:left}
th{background:#eef0f6}.pics{display:flex;flex-wrap:wrap;gap:12px}figure{margin:0}.pics img{max-width:520px;width:100%}
figcaption{font-size:.85em;color:#445}section.entry{border-left:6px solid #999;padding:.4em 1em;margin:1.4em 0;
background:#fafbfd}section.missed{border-color:#c0c}section.false_alarm{border-color:#e08000}
section.uncertain{border-color:#0aa}pre{background:#f1f2f6;padding:.5em;overflow-x:auto;font-size:.85em}
table.sup{font-size:.85em}code{background:#f1f2f6;padding:0 3px}
"""
    return (f"<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{css}</style></head><body>\n{body}\n</body></html>\n")


# ----------------------------------------------------------------------------- command
def cmd_report(args) -> int:
    """crowdcam report SET [--out DIR] [--gt DIR] [--preset P] [--max-side N] [--threshold T]
    [--max-entries K]: detect (cached pairs reused), gallery per reference, report written."""
    from crowdcam.cli import CliError, Reporter, _cache, _params
    from pipeline.evaluate import jaccard
    from pipeline.loading import is_inside, load_gts, load_set
    from pipeline.output import to_original
    from pipeline.run import detect_set

    t0 = time.perf_counter()
    rep = Reporter(args.quiet)
    params = _params(args)
    threshold = params.aggregate.threshold if args.threshold is None else args.threshold
    if not 0.0 <= threshold <= 1.0:
        raise CliError(f"--threshold must be in [0, 1] (got {threshold})")
    if args.max_entries < 1:
        raise CliError(f"--max-entries must be 1 or more (got {args.max_entries})")
    set_dir = Path(args.set)
    photo_set = load_set(set_dir, params.max_side, warn=rep.warn, gt_dir=Path(args.gt) if args.gt else None)
    params = params.for_working_side(photo_set.working_side)
    out = Path(args.out) if args.out else Path.cwd() / "crowdcam-out" / photo_set.name / "report"
    if is_inside(out, set_dir):
        raise CliError(f"{out}: the output folder must not be inside the input folder {set_dir}")
    rep.info(f"{photo_set.name}: {len(photo_set.photos)} photos, preset {params.preset}, "
             f"working size {params.max_side} px")
    res = detect_set(photo_set, params, _cache(args, rep), workers=args.workers, progress=rep.progress, warn=rep.warn,
                     max_supports=args.max_supports)
    rep.close()
    t1 = time.perf_counter()
    gts = load_gts(photo_set)
    galleries: dict[int, Gallery] = {}
    scores: dict[str, float] = {}
    refs = [i for i, d in enumerate(res.dynamic) if d is not None]
    for n, i in enumerate(refs):
        photo = photo_set.photos[i]
        galleries[i] = build_gallery(res, i, gts.get(photo.stem), threshold, args.max_entries)
        if photo.stem in gts:
            scores[photo.stem] = jaccard(to_original(res.dynamic[i], photo) > threshold, gts[photo.stem])
    t2 = time.perf_counter()
    seconds = {"detect_s": round(t1 - t0, 2), "gallery_s": round(t2 - t1, 2)}
    seconds["total_s"] = round(time.perf_counter() - t0, 2)     # without writing (a few seconds at most)
    write_report(res, galleries, gts, out, str(args.set), threshold, seconds, scores, tuple(args.param or ()))
    n = sum(len(g.entries) for g in galleries.values())
    rep.info(f"wrote {out / 'report.html'} and report.md ({n} regions from {len(galleries)} photos, "
             f"{time.perf_counter() - t0:.1f} s, {res.cache_hits} pairs cached)")
    return 0


def add_parser(sub, common) -> None:
    """Register `crowdcam report` (called by cli.build_parser)."""
    r = sub.add_parser("report", help="failure gallery of a set as report.md / report.html with pictures")
    r.add_argument("set", help="folder of photos, or folder with images/ (and optional gt/)")
    r.add_argument("--out", default=None, help="report folder (default ./crowdcam-out/<set name>/report)")
    r.add_argument("--gt", default=None, metavar="DIR",
                   help="ground-truth masks <photo stem>.png (default: gt/ beside the photos or beside images/)")
    r.add_argument("--threshold", type=float, default=None, help="mask threshold on P_dynamic (default 0.5)")
    r.add_argument("--max-entries", type=int, default=5, metavar="K",
                   help="at most K regions of each kind per photo (default 5)")
    r.add_argument("--max-supports", type=int, default=None, metavar="K",
                   help="at most K supports per photo, as `crowdcam detect` (default: 8 for sets of more than 9 photos)")
    r.add_argument("--param", action="append", metavar="SECTION.FIELD=VALUE",
                   help="change one setting of the preset (repeatable), as `crowdcam detect`")
    common(r)
    r.set_defaults(fn=cmd_report)
