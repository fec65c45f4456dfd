# ruff: noqa: E501  (the embedded JavaScript keeps its own line lengths)
"""Offline interactive 3-D viewer of a planned path: one self-contained HTML file.

No CDN, no external script: the data is embedded as JSON and drawn by a small canvas-2D renderer
written here (depth-sorted, flat-shaded triangles; the robot's tubes as thick segments). Drag to
rotate, shift-drag (or right-drag) to pan, wheel to zoom; a slider and a play button step along the
path; obstacle names in the legend toggle their visibility; a scale bar gives lengths in mm.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ctrplan.scene import Scene

_PALETTE = ["#8da0cb", "#fc8d62", "#66c2a5", "#e78ac3", "#a6d854", "#ffd92f", "#e5c494", "#b3b3b3",
            "#1f78b4", "#33a02c", "#fb9a99", "#cab2d6", "#fdbf6f", "#b15928", "#6a3d9a", "#999999"]


def viewer_data(scene: Scene, backbones_scene: np.ndarray, radii: np.ndarray,
                info: dict | None = None, max_triangles: int = 40000) -> dict:
    """The JSON document the viewer draws: obstacles, backbones (K, N, 3) with radii (K, N), target."""
    obstacles = []
    total = 0
    pts = np.asarray(backbones_scene, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    size = float(np.ptp(np.vstack([pts, scene.target.center[None]]), axis=0).max()) if len(pts) else 100.0
    for i, o in enumerate(scene.obstacles):
        m = o.to_trimesh()
        v = np.round(np.asarray(m.vertices, dtype=float), 2)
        f = np.asarray(m.faces, dtype=int)
        total += len(f)
        big = float(np.ptp(v, axis=0).max()) > 0.8 * size  # e.g. a face plate: keep it faint
        obstacles.append({"name": o.name, "color": _PALETTE[i % len(_PALETTE)],
                          "vertices": v.ravel().tolist(), "faces": f.ravel().tolist(),
                          "alpha": 0.08 if big else 0.35})
    if total > max_triangles:
        step = int(np.ceil(total / max_triangles))
        for o in obstacles:
            f = np.asarray(o["faces"]).reshape(-1, 3)[::step]
            o["faces"] = f.ravel().tolist()
    bbs = np.where(np.isfinite(backbones_scene), backbones_scene, 0.0)
    t = scene.target
    return {
        "scene": scene.name,
        "obstacles": obstacles,
        "backbones": np.round(bbs, 3).tolist(),
        "radii": np.round(np.asarray(radii, dtype=float), 3).tolist(),
        "target": {"center": t.center.tolist(), "semi_axes": t.semi_axes.tolist(),
                   "rotation": t.rotation.tolist()},
        "info": info or {},
    }


def write_viewer(path: str | Path, data: dict, title: str = "ctrplan") -> Path:
    """Write the self-contained HTML viewer for `viewer_data` output."""
    path = Path(path)
    payload = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
    html = _TEMPLATE.replace("__TITLE__", _escape(title)).replace("__DATA__", payload)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html, encoding="utf-8")
    return path


def _escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


_TEMPLATE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>__TITLE__</title>
<style>
 body{margin:0;font:13px system-ui,sans-serif;background:#f4f4f2;color:#222;overflow:hidden}
 #bar{position:absolute;left:0;right:0;bottom:0;padding:6px 10px;background:#fffd;display:flex;gap:10px;align-items:center}
 #bar input[type=range]{flex:1}
 #legend{position:absolute;top:8px;left:8px;background:#fffd;padding:6px 8px;border-radius:4px;max-height:70vh;overflow:auto}
 #legend div{cursor:pointer;user-select:none;white-space:nowrap}
 #legend span{display:inline-block;width:10px;height:10px;margin-right:5px;vertical-align:middle}
 #info{position:absolute;top:8px;right:8px;background:#fffd;padding:6px 8px;border-radius:4px;white-space:pre;font-family:monospace;font-size:11px}
 canvas{display:block}
</style></head><body>
<canvas id="c"></canvas>
<div id="legend"><b>__TITLE__</b></div><div id="info"></div>
<div id="bar"><button id="play">&#9654;</button><span id="lab">state 0</span>
<input id="slider" type="range" min="0" max="0" value="0"><label><input id="ghost" type="checkbox" checked> path</label>
<button id="reset">reset view</button></div>
<script id="data" type="application/json">__DATA__</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("data").textContent);
const cv = document.getElementById("c"), ctx = cv.getContext("2d");
const K = D.backbones.length;
const slider = document.getElementById("slider"); slider.max = Math.max(0, K - 1); slider.value = Math.max(0, K - 1);
// ---- geometry -------------------------------------------------------------------------------
const obs = D.obstacles.map(o => ({name: o.name, color: o.color, v: o.vertices, f: o.faces, on: true, alpha: o.alpha}));
function hex(c){return [parseInt(c.slice(1,3),16),parseInt(c.slice(3,5),16),parseInt(c.slice(5,7),16)];}
obs.forEach(o => o.rgb = hex(o.color));
// target ellipsoid as a triangle mesh
(function(){
  const t = D.target, n = 16, m = 8, v = [], f = [];
  for (let i = 0; i <= m; i++) for (let j = 0; j < n; j++) {
    const th = Math.PI * i / m, ph = 2 * Math.PI * j / n;
    const p = [Math.sin(th)*Math.cos(ph)*t.semi_axes[0], Math.sin(th)*Math.sin(ph)*t.semi_axes[1], Math.cos(th)*t.semi_axes[2]];
    for (let a = 0; a < 3; a++) v.push(t.center[a] + t.rotation[a][0]*p[0] + t.rotation[a][1]*p[1] + t.rotation[a][2]*p[2]);
  }
  for (let i = 0; i < m; i++) for (let j = 0; j < n; j++) {
    const a = i*n+j, b = i*n+(j+1)%n, c = (i+1)*n+j, d = (i+1)*n+(j+1)%n; f.push(a,c,b, b,c,d);
  }
  obs.push({name: "target", color: "#2ca02c", rgb: [44,160,44], v: v, f: f, on: true, alpha: 0.55});
})();
// legend
const lg = document.getElementById("legend");
obs.forEach(o => { const d = document.createElement("div"); d.innerHTML = '<span style="background:'+o.color+'"></span>'+o.name;
  d.onclick = () => { o.on = !o.on; d.style.opacity = o.on ? 1 : 0.35; draw(); }; lg.appendChild(d); });
document.getElementById("info").textContent = Object.entries(D.info).map(([k,v]) => k + ": " + (typeof v === "number" ? (+v.toFixed(3)) : JSON.stringify(v))).join("\n");
// view centre: robot + target bounds
let lo = [1e9,1e9,1e9], hi = [-1e9,-1e9,-1e9];
D.backbones.forEach(b => b.forEach(p => { for (let a=0;a<3;a++){ lo[a]=Math.min(lo[a],p[a]); hi[a]=Math.max(hi[a],p[a]); }}));
for (let a=0;a<3;a++){ lo[a]=Math.min(lo[a],D.target.center[a]); hi[a]=Math.max(hi[a],D.target.center[a]); }
const C0 = [0,1,2].map(a => (lo[a]+hi[a])/2), R0 = Math.max(20, Math.hypot(hi[0]-lo[0],hi[1]-lo[1],hi[2]-lo[2])/2);
let yaw, pitch, dist, ctr;
function reset(){ yaw = -0.9; pitch = 0.35; dist = 2.6*R0; ctr = C0.slice(); }
reset();
// ---- camera ---------------------------------------------------------------------------------
let W = 0, H = 0, F = 1, cam;
function resize(){ W = cv.width = innerWidth; H = cv.height = innerHeight; F = 0.9*Math.min(W,H); draw(); }
function basis(){
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const fw = [cp*sy, -sp, cp*cy];            // forward (scene y is up)
  const rt = [cy, 0, -sy];                   // right
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
      items.push({z:(A[2]+B[2]+Cc[2])/3, tri:[A,B,Cc], rgb:o.rgb, sh:sh, al:o.alpha||0.35});
    }
  }
  const k = +slider.value;
  const seg = (bb, rr, col, wmin) => { for (let i=0;i+1<bb.length;i++) { const A = proj(bb[i]), B = proj(bb[i+1]);
      if (A[2] < 1 || B[2] < 1) continue; const r = Math.max(rr[i], rr[i+1]);
      items.push({z:(A[2]+B[2])/2 - 0.5, line:[A,B], w:Math.max(wmin, 2*r*F/((A[2]+B[2])/2)), col:col}); } };
  if (document.getElementById("ghost").checked && K > 1) {
    const step = Math.max(1, Math.floor(K/10));
    for (let j=0;j<K;j+=step) if (j !== k) seg(D.backbones[j], D.radii[j], "rgba(60,60,160,0.35)", 1);
  }
  if (K) seg(D.backbones[k], D.radii[k], "#c0392b", 2.5);
  items.sort((a,b) => b.z - a.z);
  for (const it of items) {
    if (it.tri) { const [A,B,Cc] = it.tri; ctx.beginPath(); ctx.moveTo(A[0],A[1]); ctx.lineTo(B[0],B[1]); ctx.lineTo(Cc[0],Cc[1]); ctx.closePath();
      ctx.fillStyle = "rgba("+Math.round(it.rgb[0]*it.sh)+","+Math.round(it.rgb[1]*it.sh)+","+Math.round(it.rgb[2]*it.sh)+","+it.al+")"; ctx.fill(); }
    else { ctx.beginPath(); ctx.moveTo(it.line[0][0], it.line[0][1]); ctx.lineTo(it.line[1][0], it.line[1][1]);
      ctx.strokeStyle = it.col; ctx.lineWidth = it.w; ctx.lineCap = "round"; ctx.stroke(); }
  }
  scaleBar();
  document.getElementById("lab").textContent = "state " + k + " / " + Math.max(0, K-1);
}
// scale bar: a round length in mm, true at the depth of the view centre
function scaleBar(){
  const pxmm = F/dist, want = 140/pxmm, e = Math.pow(10, Math.floor(Math.log10(want)));
  const mm = [1,2,5,10].map(m => m*e).filter(m => m <= want).pop(), len = mm*pxmm, x0 = 20, y0 = H - 56;
  ctx.strokeStyle = "#222"; ctx.lineWidth = 2; ctx.beginPath();
  ctx.moveTo(x0,y0); ctx.lineTo(x0+len,y0); ctx.moveTo(x0,y0-5); ctx.lineTo(x0,y0+5); ctx.moveTo(x0+len,y0-5); ctx.lineTo(x0+len,y0+5); ctx.stroke();
  ctx.fillStyle = "#222"; ctx.font = "12px system-ui,sans-serif"; ctx.fillText(+mm.toPrecision(3) + " mm (at the view centre)", x0, y0-9);
}
// ---- interaction ----------------------------------------------------------------------------
let drag = null;
cv.addEventListener("mousedown", e => { drag = {x:e.clientX, y:e.clientY, pan: e.shiftKey || e.button === 2}; });
addEventListener("mouseup", () => drag = null);
cv.addEventListener("contextmenu", e => e.preventDefault());
addEventListener("mousemove", e => { if (!drag) return; const dx = e.clientX-drag.x, dy = e.clientY-drag.y; drag.x = e.clientX; drag.y = e.clientY;
  if (drag.pan) { const s = dist/F; for (let a=0;a<3;a++) ctr[a] -= (cam.rt[a]*dx - cam.up[a]*dy)*s; }
  else { yaw += dx*0.008; pitch = Math.max(-1.5, Math.min(1.5, pitch + dy*0.008)); }
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
