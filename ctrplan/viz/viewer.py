# ruff: noqa: E501  (the embedded JavaScript keeps its own line lengths)
"""Offline interactive 3-D viewer of a planned path: one self-contained HTML file.

No CDN, no external script: the data is embedded as JSON and drawn by a small canvas-2D renderer
written here (depth-sorted, flat-shaded triangles; the robot's tubes as thick segments). Drag to
rotate, shift-drag (or right-drag) to pan, wheel to zoom (a hint line says so); a slider and a play
button step along the path; obstacle names in the legend toggle their visibility; hovering an
obstacle (in the view or the legend) names it with the exact model's clearance to it along the path
and its margin; a scale bar gives lengths in mm.

What a surgeon looks for is marked: the target in a colour no obstacle has (outlined and named
on top of everything), the tip, the exact model's clearance as a colour along the backbone (with
its scale and the state's minimum), anatomical orientation (the scene's `anatomy` directions on an
axis triad) and the result as labelled lines. The first view is framed on the corridor, seen from
the side; an obstacle much larger than the corridor (a face plate) is drawn faint.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ctrplan.base.dataio import atomic_write
from ctrplan.scene.objects import Scene
from ctrplan.viz.display_mesh import DISPLAY_FACES, display_mesh
from ctrplan.viz.framing import corridor_bounds, corridor_direction, finite_points
from ctrplan.viz.style import (
    CLEARANCE_CAP_MM,
    CLEARANCE_STOPS,
    TARGET_COLOR,
    axis_labels,
    scene_colors,
)


def viewer_data(scene: Scene, backbones_scene: np.ndarray, radii: np.ndarray,
                info: dict[str, str] | None = None, clearance_mm: np.ndarray | None = None,
                max_triangles: int = 40000,
                structures: dict[str, tuple[str, bool]] | None = None) -> dict:
    """The JSON document the viewer draws: obstacles, backbones (K, N, 3) with radii (K, N) and the
    clearance of each segment (K, N-1) (mm, surface to nearest obstacle, capped at
    `CLEARANCE_CAP_MM`; None: not shown), the target, the first view, the axis names, ``info``
    (label -> text, shown as labelled lines) and ``structures`` (obstacle name -> (its clearance
    as text, whether it is below its margin): shown on hover, warnings in red). The structures are
    drawn from `display_mesh`: ``max_triangles`` in all, shared evenly, and at most `DISPLAY_FACES`
    each."""
    bounds = corridor_bounds(backbones_scene, scene)
    size = float(np.ptp(bounds, axis=0).max())
    colours = scene_colors(scene.obstacles)
    obstacles = []
    budget = min(DISPLAY_FACES, max_triangles // max(len(scene.obstacles), 1))
    for o in scene.obstacles:
        vertices, faces = display_mesh(o, budget)
        v = np.round(vertices, 2)
        backdrop = float(np.ptp(v, axis=0).max()) > 1.5 * size
        note, warn = (structures or {}).get(o.name, ("", False))
        obstacles.append({"name": o.name, "color": colours[o.name], "vertices": v.ravel().tolist(),
                          "faces": faces.ravel().tolist(), "alpha": 0.05 if backdrop else 0.35,
                          "note": note, "warn": bool(warn)})
    bbs = np.where(np.isfinite(backbones_scene), backbones_scene, 0.0)
    t = scene.target
    clearance = None if clearance_mm is None else np.round(np.nan_to_num(clearance_mm, nan=0.0), 3).tolist()
    return {
        "scene": scene.name,
        "obstacles": obstacles,
        "backbones": np.round(bbs, 3).tolist(),
        "radii": np.round(np.asarray(radii, dtype=float), 3).tolist(),
        "clearance": clearance,
        "clearance_cap": CLEARANCE_CAP_MM,
        "clearance_stops": [list(s) for s in CLEARANCE_STOPS],
        "target": {"center": t.center.tolist(), "semi_axes": t.semi_axes.tolist(),
                   "rotation": t.rotation.tolist(), "color": TARGET_COLOR},
        "view": _first_view(backbones_scene, bounds),
        "axes": axis_labels(scene.anatomy),
        "info": [[k, str(v)] for k, v in (info or {}).items()],
    }


def _first_view(backbones: np.ndarray, bounds: np.ndarray) -> dict:
    """Camera of the first view (the viewer's y is up): centred on the corridor ``bounds``, looking
    across the corridor's direction, turned 35 degrees towards its start and 20 degrees down."""
    d = corridor_direction(backbones, bounds)
    yaw = math.atan2(d[2], -d[0]) if math.hypot(d[0], d[2]) > 0.3 else -0.9
    centre = bounds.mean(axis=0)
    pts = finite_points(np.asarray(backbones)[-1:])
    if len(pts):  # keep the last backbone's tip region in the middle of the picture
        centre = 0.5 * (centre + np.clip(pts.mean(axis=0), bounds[0], bounds[1]))
    return {"center": centre.tolist(), "radius": float(np.linalg.norm(np.ptp(bounds, axis=0)) / 2),
            "yaw": yaw + math.radians(35.0), "pitch": math.radians(20.0)}


def write_viewer(path: str | Path, data: dict, title: str = "ctrplan") -> Path:
    """Write the self-contained HTML viewer for `viewer_data` output."""
    path = Path(path)
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    html = _TEMPLATE.replace("__TITLE__", _escape(title)).replace("__DATA__", payload)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as fh:
        fh.write(html)
    return path


def _escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


_TEMPLATE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
 body{margin:0;font:13px system-ui,sans-serif;background:#f4f4f2;color:#222;overflow:hidden}
 #bar{position:absolute;left:0;right:0;bottom:0;padding:6px 10px;background:#fffd;display:flex;gap:10px;align-items:center}
 #bar input[type=range]{flex:1}
 .panel{position:absolute;background:#fffe;padding:6px 9px;border-radius:4px;box-shadow:0 1px 3px #0002}
 #legend{top:8px;left:8px;max-height:62vh;overflow:auto}
 #legend div{cursor:pointer;user-select:none;white-space:nowrap;line-height:1.45}
 #legend span{display:inline-block;width:11px;height:11px;margin-right:6px;vertical-align:middle;border:1px solid #0003}
 #legend .target{font-weight:bold}
 #info{top:8px;right:8px;max-width:34vw}
 #info table{border-collapse:collapse}
 #info th{text-align:left;font-weight:600;padding:1px 10px 1px 0;color:#444;vertical-align:top;white-space:nowrap}
 #info td{padding:1px 0}
 #info .title{font-weight:bold;font-size:14px;margin-bottom:3px}
 #state{min-width:260px}
 #hint{top:auto;bottom:44px;left:8px;font-size:12px;color:#444;background:#fffc}
 #tip{position:absolute;display:none;pointer-events:none;background:#222e;color:#fff;padding:4px 8px;border-radius:3px;font-size:12px;white-space:nowrap}
 #tip.warn{background:#b0001ae8}
 #legend .warn{color:#b0001a;font-weight:bold}
 canvas{display:block}
</style></head><body>
<canvas id="c"></canvas>
<div id="legend" class="panel"><b>__TITLE__</b></div><div id="info" class="panel"></div>
<div id="hint" class="panel">drag: rotate &middot; shift-drag or right-drag: pan &middot; wheel: zoom &middot; hover a structure: its clearance &middot; click a legend name: hide it</div>
<div id="tip"></div>
<div id="bar"><button id="play">&#9654;</button><span id="state">state 0</span>
<input id="slider" type="range" min="0" max="0" value="0"><label><input id="ghost" type="checkbox" checked> path</label>
<button id="reset">reset view</button></div>
<script id="data" type="application/json">__DATA__</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("data").textContent);
const cv = document.getElementById("c"), ctx = cv.getContext("2d");
const K = D.backbones.length;
const slider = document.getElementById("slider"); slider.max = Math.max(0, K - 1); slider.value = Math.max(0, K - 1);
const esc = s => String(s).replace(/&/g,"&amp;").replace(/</g,"&lt;").replace(/>/g,"&gt;");
// ---- geometry -------------------------------------------------------------------------------
const obs = D.obstacles.map(o => ({name: o.name, color: o.color, v: o.vertices, f: o.faces, on: true, alpha: o.alpha, note: o.note, warn: o.warn}));
function hex(c){return [parseInt(c.slice(1,3),16),parseInt(c.slice(3,5),16),parseInt(c.slice(5,7),16)];}
obs.forEach(o => o.rgb = hex(o.color));
// target ellipsoid as a triangle mesh
(function(){
  const t = D.target, n = 18, m = 9, v = [], f = [];
  for (let i = 0; i <= m; i++) for (let j = 0; j < n; j++) {
    const th = Math.PI * i / m, ph = 2 * Math.PI * j / n;
    const p = [Math.sin(th)*Math.cos(ph)*t.semi_axes[0], Math.sin(th)*Math.sin(ph)*t.semi_axes[1], Math.cos(th)*t.semi_axes[2]];
    for (let a = 0; a < 3; a++) v.push(t.center[a] + t.rotation[a][0]*p[0] + t.rotation[a][1]*p[1] + t.rotation[a][2]*p[2]);
  }
  for (let i = 0; i < m; i++) for (let j = 0; j < n; j++) {
    const a = i*n+j, b = i*n+(j+1)%n, c = (i+1)*n+j, d = (i+1)*n+(j+1)%n; f.push(a,c,b, b,c,d);
  }
  obs.push({name: "target", color: t.color, rgb: hex(t.color), v: v, f: f, on: true, alpha: 0.7, target: true});
})();
// legend
const lg = document.getElementById("legend");
obs.forEach(o => { const d = document.createElement("div"); d.innerHTML = '<span style="background:'+o.color+'"></span>'+esc(o.name);
  if (o.target) d.className = "target"; else if (o.warn) d.className = "warn";
  d.onmouseenter = e => showTip(o, e.clientX + 14, e.clientY); d.onmouseleave = hideTip;
  d.onclick = () => { o.on = !o.on; d.style.opacity = o.on ? 1 : 0.35; draw(); }; lg.appendChild(d); });
// result: labelled lines
document.getElementById("info").innerHTML = '<div class="title">' + esc(D.scene) + '</div><table>' +
  D.info.map(([k, v]) => "<tr><th>" + esc(k) + "</th><td>" + esc(v) + "</td></tr>").join("") + "</table>";
// clearance colours along the backbone
const stops = D.clearance_stops.map(([f, c]) => [f, hex(c)]);
function clearColor(c){
  const f = Math.max(0, Math.min(1, c / D.clearance_cap));
  let i = 0; while (i + 2 < stops.length && f > stops[i+1][0]) i++;
  const [f0, a] = stops[i], [f1, b] = stops[i+1], u = Math.max(0, Math.min(1, (f - f0) / (f1 - f0)));
  return "rgb(" + [0,1,2].map(k => Math.round(a[k] + u*(b[k]-a[k]))).join(",") + ")";
}
let yaw, pitch, dist, ctr;
function reset(){ yaw = D.view.yaw; pitch = D.view.pitch; dist = 2.2*D.view.radius; ctr = D.view.center.slice(); }
reset();
// ---- camera ---------------------------------------------------------------------------------
let W = 0, H = 0, F = 1, cam;
function resize(){ W = cv.width = innerWidth; H = cv.height = innerHeight; F = 0.9*Math.min(W,H); draw(); }
function basis(){
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const fw = [cp*sy, -sp, cp*cy];            // forward (scene y is up)
  const rt = [-cy, 0, sy];                   // right = forward x up: a rotation, never a mirror image
  const up = [rt[1]*fw[2]-rt[2]*fw[1], rt[2]*fw[0]-rt[0]*fw[2], rt[0]*fw[1]-rt[1]*fw[0]];
  const eye = [ctr[0]-fw[0]*dist, ctr[1]-fw[1]*dist, ctr[2]-fw[2]*dist];
  return {fw, rt, up, eye};
}
function proj(p){ // -> [sx, sy, depth]
  const d = [p[0]-cam.eye[0], p[1]-cam.eye[1], p[2]-cam.eye[2]];
  const z = d[0]*cam.fw[0]+d[1]*cam.fw[1]+d[2]*cam.fw[2];
  const x = d[0]*cam.rt[0]+d[1]*cam.rt[1]+d[2]*cam.rt[2];
  const y = d[0]*cam.up[0]+d[1]*cam.up[1]+d[2]*cam.up[2];
  const s = F/Math.max(z, 1e-3);
  return [W/2 + x*s, H/2 - y*s, z];
}
const light = () => { const l = [cam.fw[0]*-0.6+cam.up[0]*0.5+cam.rt[0]*0.3, cam.fw[1]*-0.6+cam.up[1]*0.5+cam.rt[1]*0.3, cam.fw[2]*-0.6+cam.up[2]*0.5+cam.rt[2]*0.3];
  const n = Math.hypot(...l); return l.map(x => x/n); };
// ---- drawing --------------------------------------------------------------------------------
function draw(){
  if (!W) return;
  cam = basis(); const L = light();
  ctx.fillStyle = "#f4f4f2"; ctx.fillRect(0,0,W,H);
  const items = [];
  for (const o of obs) { if (!o.on) continue;
    const v = o.v, f = o.f, P = new Array(v.length/3);
    for (let i=0;i<P.length;i++) P[i] = proj([v[3*i],v[3*i+1],v[3*i+2]]);
    for (let t=0;t<f.length;t+=3) {
      const a=f[t], b=f[t+1], c=f[t+2], A=P[a], B=P[b], Cc=P[c];
      if (A[2] < 1 || B[2] < 1 || Cc[2] < 1) continue;
      const ux=v[3*b]-v[3*a], uy=v[3*b+1]-v[3*a+1], uz=v[3*b+2]-v[3*a+2], wx=v[3*c]-v[3*a], wy=v[3*c+1]-v[3*a+1], wz=v[3*c+2]-v[3*a+2];
      let nx=uy*wz-uz*wy, ny=uz*wx-ux*wz, nz=ux*wy-uy*wx; const nn=Math.hypot(nx,ny,nz)||1;
      const sh = 0.45 + 0.55*Math.abs((nx*L[0]+ny*L[1]+nz*L[2])/nn);
      items.push({z:(A[2]+B[2]+Cc[2])/3, tri:[A,B,Cc], rgb:o.rgb, sh:sh, al:o.alpha||0.35, o:o});
    }
  }
  const k = +slider.value;
  const seg = (bb, rr, col, wmin, outline) => { const P = bb.map(proj), far = Math.max(...P.map(p => p[2])) + 1;
    for (let i=0;i+1<bb.length;i++) { const A = P[i], B = P[i+1];
      if (A[2] < 1 || B[2] < 1) continue; const r = Math.max(rr[i], rr[i+1]), z = (A[2]+B[2])/2;
      const w = Math.max(wmin, 2*r*F/z), c = typeof col === "function" ? col(i) : col;
      if (outline) items.push({z:far, line:[A,B], w:w + 2.5, col:"#222"});  // under the whole backbone
      items.push({z:z - 0.5, line:[A,B], w:w, col:c}); } };
  if (document.getElementById("ghost").checked && K > 1) {
    const step = Math.max(1, Math.floor(K/10));
    for (let j=0;j<K;j+=step) if (j !== k) seg(D.backbones[j], D.radii[j], "rgba(70,80,120,0.28)", 1, false);
  }
  const cl = D.clearance ? D.clearance[k] : null;
  if (K) seg(D.backbones[k], D.radii[k], cl ? (i => clearColor(cl[i])) : "#333", 4, true);
  items.sort((a,b) => b.z - a.z);
  drawn = items;
  for (const it of items) {
    if (it.tri) { const [A,B,Cc] = it.tri; ctx.beginPath(); ctx.moveTo(A[0],A[1]); ctx.lineTo(B[0],B[1]); ctx.lineTo(Cc[0],Cc[1]); ctx.closePath();
      ctx.fillStyle = "rgba("+Math.round(it.rgb[0]*it.sh)+","+Math.round(it.rgb[1]*it.sh)+","+Math.round(it.rgb[2]*it.sh)+","+it.al+")"; ctx.fill(); }
    else { ctx.beginPath(); ctx.moveTo(it.line[0][0], it.line[0][1]); ctx.lineTo(it.line[1][0], it.line[1][1]);
      ctx.strokeStyle = it.col; ctx.lineWidth = it.w; ctx.lineCap = "round"; ctx.stroke(); }
  }
  marks(k); scaleBar(); triad(); if (D.clearance) clearanceBar();
  let text = "state " + k + " / " + Math.max(0, K-1);
  if (cl) { const c = Math.min(...cl); text += " \u00b7 min clearance " + (c >= D.clearance_cap ? "\u2265 " + D.clearance_cap : c.toFixed(2)) + " mm"; }
  document.getElementById("state").textContent = text;
}
function label(text, x, y, color){
  ctx.font = "bold 13px system-ui,sans-serif"; ctx.lineWidth = 4; ctx.strokeStyle = "#fff"; ctx.lineJoin = "round";
  ctx.strokeText(text, x, y); ctx.fillStyle = color; ctx.fillText(text, x, y);
}
// on top of everything: the target's outline and name, the tip and its name
function marks(k){
  const t = D.target, C = proj(t.center);
  if (C[2] > 1 && obs[obs.length-1].on) {
    const r = Math.max(7, Math.max(...t.semi_axes)*F/C[2]);
    ctx.setLineDash([5, 4]); ctx.lineWidth = 2.5; ctx.strokeStyle = "#003c55";
    ctx.beginPath(); ctx.arc(C[0], C[1], r + 3, 0, 2*Math.PI); ctx.stroke(); ctx.setLineDash([]);
    label("target", C[0] + r + 8, C[1] - r - 4, "#006b94");
  }
  if (!K) return;
  const bb = D.backbones[k], P = bb.map(proj), cl = D.clearance ? D.clearance[k] : null;
  ctx.globalAlpha = 0.6; ctx.lineCap = "round";  // the backbone seen through the anatomy in front of it
  for (let i=0;i+1<P.length;i++) { if (P[i][2] < 1 || P[i+1][2] < 1) continue;
    ctx.strokeStyle = cl ? clearColor(cl[i]) : "#333"; ctx.lineWidth = 3;
    ctx.beginPath(); ctx.moveTo(P[i][0], P[i][1]); ctx.lineTo(P[i+1][0], P[i+1][1]); ctx.stroke(); }
  ctx.globalAlpha = 1;
  const T = P[P.length-1];
  if (T[2] < 1) return;
  ctx.beginPath(); ctx.arc(T[0], T[1], 6, 0, 2*Math.PI); ctx.fillStyle = "#fff"; ctx.fill();
  ctx.lineWidth = 2.5; ctx.strokeStyle = "#111"; ctx.stroke();
  label("tip", T[0] - 12, T[1] + 22, "#111");
}
// orientation: the scene axes from the camera, named by the patient directions when the scene gives them
function triad(){
  const x0 = W - 95, y0 = H - 120, len = 42, cols = {x: "#c0392b", y: "#2e8b57", z: "#2c5aa0"};
  ctx.fillStyle = "#fffc"; ctx.beginPath(); ctx.arc(x0, y0, len + 34, 0, 2*Math.PI); ctx.fill();
  [["x", [1,0,0]], ["y", [0,1,0]], ["z", [0,0,1]]].forEach(([a, e]) => {
    const dx = e[0]*cam.rt[0]+e[1]*cam.rt[1]+e[2]*cam.rt[2], dy = -(e[0]*cam.up[0]+e[1]*cam.up[1]+e[2]*cam.up[2]);
    [[1, D.axes[a][0], 2.5, cols[a]], [-1, D.axes[a][1], 1, "#777"]].forEach(([s, name, w, c]) => {
      ctx.strokeStyle = c; ctx.lineWidth = w; ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x0 + s*dx*len, y0 + s*dy*len); ctx.stroke();
      ctx.font = (s > 0 ? "bold " : "") + "11px system-ui,sans-serif"; ctx.fillStyle = c; ctx.textAlign = "center";
      ctx.fillText(name, x0 + s*dx*(len + 14), y0 + s*dy*(len + 14) + 4); ctx.textAlign = "start";
    });
  });
}
function clearanceBar(){
  const x0 = 20, y0 = H - 138, w = 190, h = 10, g = ctx.createLinearGradient(x0, 0, x0 + w, 0);
  stops.forEach(([f, c]) => g.addColorStop(f, "rgb(" + c.join(",") + ")"));
  ctx.fillStyle = "#fffc"; ctx.fillRect(x0 - 6, y0 - 20, w + 80, 42);
  ctx.fillStyle = g; ctx.fillRect(x0, y0, w, h); ctx.strokeStyle = "#333"; ctx.lineWidth = 1; ctx.strokeRect(x0, y0, w, h);
  ctx.fillStyle = "#222"; ctx.font = "12px system-ui,sans-serif";
  ctx.fillText("clearance to the obstacles (exact model)", x0, y0 - 6);
  for (let v = 0; v <= D.clearance_cap; v++) ctx.fillText(v + (v === D.clearance_cap ? "+ mm" : ""), x0 + w*v/D.clearance_cap - 3, y0 + h + 12);
}
// scale bar: a round length in mm, true at the depth of the view centre
function scaleBar(){
  const pxmm = F/dist, want = 140/pxmm, e = Math.pow(10, Math.floor(Math.log10(want)));
  const mm = [1,2,5,10].map(m => m*e).filter(m => m <= want).pop(), len = mm*pxmm, x0 = 20, y0 = H - 82;
  ctx.strokeStyle = "#222"; ctx.lineWidth = 2; ctx.beginPath();
  ctx.moveTo(x0,y0); ctx.lineTo(x0+len,y0); ctx.moveTo(x0,y0-5); ctx.lineTo(x0,y0+5); ctx.moveTo(x0+len,y0-5); ctx.lineTo(x0+len,y0+5); ctx.stroke();
  ctx.fillStyle = "#222"; ctx.font = "12px system-ui,sans-serif"; ctx.fillText(+mm.toPrecision(3) + " mm (at the view centre)", x0, y0-9);
}
// ---- hover: the structure under the pointer (nearest drawn triangle) with its clearance ------------
let drawn = [];
const tipEl = document.getElementById("tip");
function showTip(o, x, y){
  tipEl.textContent = o.name + (o.target ? "" : " \u00b7 nearest along the path: " + (o.note || "not computed (no checked path)"));
  tipEl.className = o.warn ? "warn" : ""; tipEl.style.display = "block";
  tipEl.style.left = Math.min(x, W - tipEl.offsetWidth - 8) + "px"; tipEl.style.top = (y + 16) + "px";
}
function hideTip(){ tipEl.style.display = "none"; }
function inside(p, [A, B, C]){
  const s = (P, Q, R) => (Q[0]-P[0])*(R[1]-P[1]) - (Q[1]-P[1])*(R[0]-P[0]);
  const a = s(A, B, p), b = s(B, C, p), c = s(C, A, p);
  return (a >= 0 && b >= 0 && c >= 0) || (a <= 0 && b <= 0 && c <= 0);
}
function hover(e){
  const p = [e.clientX, e.clientY];
  for (let i = drawn.length - 1; i >= 0; i--) { const it = drawn[i];
    if (it.tri && it.o.alpha >= 0.1 && inside(p, it.tri)) { showTip(it.o, p[0] + 14, p[1]); return; } }
  hideTip();
}
// ---- interaction ----------------------------------------------------------------------------
let drag = null;
cv.addEventListener("mousedown", e => { drag = {x:e.clientX, y:e.clientY, pan: e.shiftKey || e.button === 2}; });
addEventListener("mouseup", () => drag = null);
cv.addEventListener("contextmenu", e => e.preventDefault());
cv.addEventListener("mousemove", e => { if (!drag) hover(e); });
cv.addEventListener("mouseleave", hideTip);
addEventListener("mousemove", e => { if (!drag) return; hideTip(); const dx = e.clientX-drag.x, dy = e.clientY-drag.y; drag.x = e.clientX; drag.y = e.clientY;
  if (drag.pan) { const s = dist/F; for (let a=0;a<3;a++) ctr[a] -= (cam.rt[a]*dx - cam.up[a]*dy)*s; }
  else { yaw -= dx*0.008; pitch = Math.max(-1.5, Math.min(1.5, pitch + dy*0.008)); }
  draw(); });
cv.addEventListener("wheel", e => { e.preventDefault(); dist *= Math.exp(e.deltaY*0.001); draw(); }, {passive:false});
slider.addEventListener("input", draw);
document.getElementById("ghost").addEventListener("change", draw);
document.getElementById("reset").onclick = () => { reset(); draw(); };
let timer = null;
document.getElementById("play").onclick = () => { if (timer) { clearInterval(timer); timer = null; return; }
  if (+slider.value >= K-1) slider.value = 0;
  timer = setInterval(() => { if (+slider.value >= K-1) { clearInterval(timer); timer = null; return; } slider.value = +slider.value + 1; draw(); }, 60); };
addEventListener("resize", resize);
resize();
</script></body></html>
"""
