"""The reference picker (issue 13 item 5): every photo of the set as a thumbnail, one click to show it.

Built for a hundred photos. The thumbnails are downsized and JPEG-encoded once, when the
inspector starts (`Thumbnails`), into one HTML grid that every tab shows as it is: one viser
element, sent once per tab and never redrawn, so the browser decodes the pictures once and the
grid keeps its scroll position. What changes (each photo's number of supports, whether its map
is ready, which photo is shown) is a small style sheet of its own (`status_css`, a few kB for
100 photos), whose rules write the words and colours into the grid's cells (CSS `content`).

viser runs no <script> from HTML, but inline event handlers do run: a click on a cell writes the
photo's index into a hidden text field of the tab (the page script finds it by its label, as the
tour's prepared link does), and the field's callback sets the Reference dropdown, so a click takes
the dropdown's own path (app.Session._on_ref). The alternatives were slower to draw or to use:
one gui.add_image per photo cannot be clicked; a button per photo has no picture and stacks 100
rows; a scene node per thumbnail puts 100 nodes in the scene (and takes the main view away from the
photo); a mosaic redrawn on every change re-encodes the pictures.
"""

from __future__ import annotations

import base64
import html
import time

import cv2
import numpy as np

from . import render
from .model import RefState

PICK_LABEL = "Picked photo"          # the hidden field a click writes to (found by this label)
THUMB_WIDTH = 128                    # encoded width, px (a cell shows it about 96 px wide)
THUMB_QUALITY = 80
STATE_COLOURS = {"ready": "#2b8a3e", "computing": "#b35900", "queued": "#5c636a", "no map": "#a61e1e",
                 "incomplete": "#5c636a", "pending": "#5c636a"}
SHOWN_RGB = "#0e4682"                # app.BRAND_RGB

_STYLE = """<style>
.cc-pick-head { font-size: 0.8rem; line-height: 1.35; margin: 0 0 6px 0; color: #212529; }
.cc-pick-head b { font-weight: 600; }
.cc-pick-key { display: inline-block; padding: 0 5px; border-radius: 3px; color: #fff; font-size: 0.72rem;
  font-weight: 600; margin-right: 2px; }
.cc-grid { display: grid; grid-template-columns: repeat(auto-fill, minmax(92px, 1fr)); gap: 6px;
  max-height: min(44vh, 440px); overflow-y: auto; resize: vertical; padding: 3px; align-content: start;
  border: 1px solid #dee2e6; border-radius: 4px; }
.cc-cell { cursor: pointer; border: 2px solid transparent; border-radius: 4px; padding: 2px; background: #fff;
  min-width: 0; }
.cc-cell:hover { border-color: #a5b4c4; }
.cc-thumb { position: relative; aspect-ratio: 4 / 3; background: #e9ecef; border-radius: 2px; overflow: hidden; }
.cc-thumb img { width: 100%; height: 100%; object-fit: contain; display: block; }
.cc-badge { position: absolute; left: 2px; bottom: 2px; padding: 0 4px; border-radius: 3px; color: #fff;
  background: #5c636a; font-size: 0.68rem; font-weight: 600; line-height: 1.35; white-space: nowrap; }
.cc-badge::after { content: "\\2026"; }
.cc-shown-tag { display: none; position: absolute; right: 2px; top: 2px; padding: 0 4px; border-radius: 3px;
  color: #fff; background: """ + SHOWN_RGB + """; font-size: 0.68rem; font-weight: 600; line-height: 1.35; }
.cc-name { font-size: 0.75rem; font-weight: 600; color: #212529; white-space: nowrap; overflow: hidden;
  text-overflow: ellipsis; margin-top: 1px; }
.cc-sup { font-size: 0.7rem; color: #454c53; white-space: nowrap; }
.cc-sup::after { content: "supports: \\2026"; }
#cc-summary { font-size: 0.78rem; color: #212529; margin: 6px 0 0 0; }
</style>"""

# Installed once per page by an image that fails to load (viser runs no <script> from HTML).
_JS = """if(!window.__ccPick){window.__ccPick=function(k){
var l=document.querySelectorAll('label'),el=null;
for(var i=0;i<l.length&&!el;i++){if(l[i].textContent.trim()!==%(label)s)continue;
 for(var p=l[i].parentElement,n=0;p&&n<5&&!el;p=p.parentElement,n++){el=p.querySelector('input');}}
if(!el)return;
var set=Object.getOwnPropertyDescriptor(HTMLInputElement.prototype,'value').set;
set.call(el,k+'|'+Date.now());el.dispatchEvent(new Event('input',{bubbles:true}));};}"""


def thumbnail_uri(rgb: np.ndarray, width: int = THUMB_WIDTH, quality: int = THUMB_QUALITY) -> str:
    """(h, w, 3) uint8 RGB -> a data: URI of the photo downsized to `width` px, as JPEG."""
    small = render.fit(rgb, min(width, rgb.shape[1]))
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(small[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def cell_id(k: int) -> str:
    return f"cc-p{k}"


def grid_html(stems: list[str], uris: list[str]) -> str:
    """The picker's HTML: how to read it, and one cell per photo (thumbnail, badge, stem, supports).
    Static: the words that change are written by status_css."""
    js = _JS % {"label": repr(PICK_LABEL)}

    def key(state, words):
        return f'<span class="cc-pick-key" style="background:{STATE_COLOURS[state]}">{words}</span>'
    head = (f'<img src="data:," alt="" style="display:none" onerror="{html.escape(js, quote=True)}">'
            '<p class="cc-pick-head"><b>Click a photo to show it</b> (the one shown is framed, and computed '
            'first). Under each photo: its supports, the other photos it is compared with. On it, its map: '
            f'{key("ready", "ready")}, {key("computing", "computing 3/8")} (3 of its 8 pairs done), '
            f'{key("queued", "queued")} or {key("no map", "no map")} (no photo to compare it with).</p>')
    cells = []
    for k, (stem, uri) in enumerate(zip(stems, uris)):
        name = html.escape(stem)
        cells.append(f'<div class="cc-cell" id="{cell_id(k)}" title="{name}: click to show its map" '
                     f'onclick="window.__ccPick({k})"><div class="cc-thumb"><img src="{uri}" alt="{name}">'
                     f'<span class="cc-badge"></span><span class="cc-shown-tag">shown</span></div>'
                     f'<div class="cc-name">{name}</div><div class="cc-sup"></div></div>')
    return _STYLE + head + '<div class="cc-grid">' + "".join(cells) + '</div><p id="cc-summary"></p>'


class Thumbnails:
    """Every photo's thumbnail and the picker's HTML, made once per inspector (shared by all tabs).
    build_ms: the time it took."""

    def __init__(self, rgbs: list[np.ndarray], stems: list[str]):
        t0 = time.perf_counter()
        self.uris = [thumbnail_uri(rgb) for rgb in rgbs]
        self.html = grid_html(stems, self.uris)
        self.build_ms = 1000 * (time.perf_counter() - t0)


def badge_text(st: RefState) -> str:
    if st.state == "computing":
        return f"computing {st.ready}/{st.supports}"
    if st.state == "incomplete":
        return f"stopped {st.ready}/{st.supports}"
    return st.state


def summary_text(states: list[RefState] | None) -> str:
    if states is None:
        return "Supports: the geometry is being estimated…"
    n = len(states)
    count = {s: sum(1 for x in states if x.state == s) for s in STATE_COLOURS}
    text = f"Maps ready: {count['ready']} of {n}"
    if count["computing"]:
        text += f" · computing: {count['computing']}"
    if count["queued"]:
        text += f" · queued: {count['queued']}"
    if count["no map"]:
        text += f" · no map: {count['no map']}"
    return text


def _css_string(text: str) -> str:
    """A CSS string literal (the words are ours; quotes and backslashes escaped all the same)."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def status_css(states: list[RefState] | None, shown: int, hidden_field: str | None = None) -> str:
    """The style sheet that writes each cell's badge and supports and frames the photo shown.
    states: per photo (None before the supports are known); shown: the reference's index;
    hidden_field: the DOM id the hidden field's label points at (its row is hidden)."""
    rules = []
    if hidden_field:
        rules.append(f'div:has(> div > div > p > label[for="{hidden_field}"]) {{ display: none !important; }}')
    if states is not None:
        by_state: dict[str, list[str]] = {}
        for k, st in enumerate(states):
            by_state.setdefault(st.state, []).append(f"#{cell_id(k)} .cc-badge")
            rules.append(f"#{cell_id(k)} .cc-badge::after {{ content: {_css_string(badge_text(st))}; }}")
            sup = "no support" if not st.supports else f"{st.supports} support" + ("s" if st.supports != 1 else "")
            rules.append(f"#{cell_id(k)} .cc-sup::after {{ content: {_css_string(sup)}; }}")
        for state, sel in by_state.items():
            rules.append(f"{','.join(sel)} {{ background: {STATE_COLOURS[state]}; }}")
    c = f"#{cell_id(shown)}"
    rules.append(f"{c} {{ border-color: {SHOWN_RGB} !important; background: #e7eef6; }} "
                 f"{c} .cc-shown-tag {{ display: inline; }} {c} .cc-name {{ color: {SHOWN_RGB}; }}")
    rules.append(f"#cc-summary::after {{ content: {_css_string(summary_text(states))}; }}")
    return "<style>\n" + "\n".join(rules) + "\n</style>"


def parse_pick(value: str, n: int) -> int | None:
    """The photo index a click wrote into the hidden field ("k|nonce"), or None for anything else."""
    head = str(value).split("|", 1)[0].strip()
    if not head.isdigit():
        return None
    k = int(head)
    return k if 0 <= k < n else None


class Picker:
    """One tab's picker: the shared grid, its status style and the hidden field a click writes to.
    Created while the tab's controls are built, right under the Reference dropdown; `draw` (from
    the tab's fast redrawer) sends the style when it changed; draw_ms: its server-side times."""

    def __init__(self, session, thumbs: Thumbnails):
        self.s = session
        gui = session.client.gui
        self.folder = gui.add_folder(f"Photos ({session.n}): pick the reference")
        with self.folder:
            self.html_grid = gui.add_html(thumbs.html)
        # outside the folder: a folded folder's elements are not in the page, and these must be
        self.txt = gui.add_text(PICK_LABEL, "", hint="written by a click on a photo of the picker")
        self.html_status = gui.add_html(status_css(None, session.settings.ref, self._field_id()))
        self.txt.on_update(lambda _ev: self._on_pick())
        self._css = self.html_status.content
        self.draw_ms: list[float] = []

    def _field_id(self) -> str:
        return str(self.txt._impl.uuid)      # the DOM id its <label for=…> names (viser's own)

    def _on_pick(self) -> None:
        k = parse_pick(self.txt.value, self.s.n)
        if k is None:
            return
        stem = self.s.app.stems[k]
        self.s._record("picked", stem)
        if self.s.dd_ref.value != stem:
            self.s.dd_ref.value = stem       # fires Session._on_ref, as a choice in the dropdown does

    def draw(self, model) -> bool:
        """Send the status style if it changed; True when sent."""
        t0 = time.perf_counter()
        css = status_css(model.reference_states(), self.s.settings.ref, self._field_id())
        if css == self._css:
            return False
        self._css = css
        self.html_status.content = css
        self.draw_ms = (self.draw_ms + [1000 * (time.perf_counter() - t0)])[-200:]
        return True
