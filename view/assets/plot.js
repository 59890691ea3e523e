// Plots of the Doppler mode: a pixel's spectrum (the exact pieces as a polyline, the
// Doppler-off spectrum beside it, lines labelled at their rest wavelengths with their
// centroids marked) and the step-by-step trace as small multiples. Also the colour bar.

/** About n "nice" tick values covering [lo, hi]. */
export function niceTicks(lo, hi, n = 6) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / n;
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Number(v.toPrecision(12)));
  return out;
}

const fmtValue = (v) => (v === 0 ? '0' : Math.abs(v) >= 1e3 || Math.abs(v) < 1e-2 ? v.toExponential(1) : String(Number(v.toPrecision(3))));

/** Sizes a canvas's backing store to its CSS box; returns the context and CSS size. */
function prepare(canvas) {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  canvas.width = Math.round(w * dpr);
  canvas.height = Math.round(h * dpr);
  const c = canvas.getContext('2d');
  c.setTransform(dpr, 0, 0, dpr, 0, 0);
  c.clearRect(0, 0, w, h);
  return { c, w, h };
}

/** Extent of the finite numbers in arrays. */
function extent(...arrays) {
  let lo = Infinity;
  let hi = -Infinity;
  for (const a of arrays)
    for (const v of a || [])
      if (Number.isFinite(v)) {
        lo = Math.min(lo, v);
        hi = Math.max(hi, v);
      }
  return [lo, hi];
}

function polyline(c, xs, ys, sx, sy) {
  c.beginPath();
  for (let i = 0; i < xs.length; i++) {
    const x = sx(xs[i]);
    const y = sy(ys[i]);
    i ? c.lineTo(x, y) : c.moveTo(x, y);
  }
  c.stroke();
}

/** Axes with ticks in the box; returns the maps data -> CSS pixels. */
function axes(c, box, [x0, x1], [y0, y1], { xTicks = 6, yTicks = 4, labels = true } = {}) {
  const sx = (v) => box.l + ((v - x0) / (x1 - x0)) * box.w;
  const sy = (v) => box.t + box.h - ((v - y0) / (y1 - y0)) * box.h;
  c.strokeStyle = '#566';
  c.strokeRect(box.l, box.t, box.w, box.h);
  c.font = '10px sans-serif';
  c.fillStyle = '#9aa3ad';
  c.textAlign = 'center';
  c.textBaseline = 'top';
  for (const v of niceTicks(x0, x1, xTicks)) {
    const x = sx(v);
    c.fillRect(x, box.t + box.h, 1, 3);
    if (labels) c.fillText(String(v), x, box.t + box.h + 4);
  }
  c.textAlign = 'right';
  c.textBaseline = 'middle';
  for (const v of niceTicks(y0, y1, yTicks)) {
    const y = sy(v);
    c.fillRect(box.l - 3, y, 3, 1);
    if (labels) c.fillText(fmtValue(v), box.l - 5, y);
  }
  return { sx, sy };
}

const SPEC_BOX = { l: 58, t: 34, r: 12, b: 32 };

/**
 * The spectrum plot of a picked pixel. The wheel zooms the wavelength axis about the
 * mouse, a drag pans it, a double-click shows the whole spectrum again. The value axis fits
 * the visible part.
 */
export class SpectrumPlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.spec = null;
    this.range = null; // visible [lo, hi] nm, null: everything
    const nmAt = (ev) => {
      const r = canvas.getBoundingClientRect();
      const [lo, hi] = this._range();
      return lo + ((ev.clientX - r.left - SPEC_BOX.l) / (r.width - SPEC_BOX.l - SPEC_BOX.r)) * (hi - lo);
    };
    canvas.addEventListener(
      'wheel',
      (ev) => {
        if (!this.spec) return;
        ev.preventDefault();
        const [lo, hi] = this._range();
        const at = nmAt(ev);
        const f = Math.exp(ev.deltaY * 0.002);
        this.range = [at - (at - lo) * f, at + (hi - at) * f];
        this.draw();
      },
      { passive: false },
    );
    let drag = null;
    canvas.addEventListener('pointerdown', (ev) => {
      if (!this.spec) return;
      canvas.setPointerCapture(ev.pointerId);
      drag = { x: ev.clientX, range: this._range() };
    });
    canvas.addEventListener('pointermove', (ev) => {
      if (!drag) return;
      const r = canvas.getBoundingClientRect();
      const [lo, hi] = drag.range;
      const d = ((ev.clientX - drag.x) / (r.width - SPEC_BOX.l - SPEC_BOX.r)) * (hi - lo);
      this.range = [lo - d, hi - d];
      this.draw();
    });
    canvas.addEventListener('pointerup', () => (drag = null));
    canvas.addEventListener('dblclick', () => {
      this.range = null;
      this.draw();
    });
  }

  /** Shows a `spectrum` reply (keeping the zoom). */
  set(spec) {
    this.spec = spec;
    this.draw();
  }

  _full() {
    const off = this.spec.off || { wavelengths: [] };
    const [lo, hi] = extent(this.spec.wavelengths, off.wavelengths);
    return hi > lo ? [lo, hi] : [lo - 1, lo + 1];
  }

  _range() {
    return this.range || this._full();
  }

  draw() {
    const spec = this.spec;
    const { c, w, h } = prepare(this.canvas);
    if (!spec) return;
    const off = spec.off || { wavelengths: [], values: [] };
    if (!Number.isFinite(this._full()[0])) {
      c.fillStyle = '#9aa3ad';
      c.fillText('empty spectrum', 10, 20);
      return;
    }
    const [x0, x1] = this._range();
    // Fit the value axis to what is visible.
    let y1 = 0;
    for (const [ws, vs] of [[spec.wavelengths, spec.values], [off.wavelengths, off.values]])
      ws.forEach((l, i) => {
        if (l >= x0 && l <= x1 && Number.isFinite(vs[i])) y1 = Math.max(y1, vs[i]);
      });
    if (!(y1 > 0)) y1 = 1;
    y1 *= 1.08;
    const box = { l: SPEC_BOX.l, t: SPEC_BOX.t, w: w - SPEC_BOX.l - SPEC_BOX.r, h: h - SPEC_BOX.t - SPEC_BOX.b };
    const { sx, sy } = axes(c, box, [x0, x1], [0, y1]);
    c.fillStyle = '#9aa3ad';
    c.textBaseline = 'bottom';
    c.textAlign = 'center';
    c.fillText('wavelength (nm)', box.l + box.w / 2, h - 2);
    c.textAlign = 'left';
    c.fillText(`pixel (${spec.x}, ${spec.y})`, 4, h - 2);
    c.textAlign = 'right';
    c.fillText('W m⁻² sr⁻¹ nm⁻¹', w - 4, h - 2);
    c.save();
    c.beginPath();
    c.rect(box.l, box.t, box.w, box.h);
    c.clip();
    c.strokeStyle = 'rgba(190,190,190,0.7)';
    c.lineWidth = 0.8;
    polyline(c, off.wavelengths, off.values, sx, sy);
    c.strokeStyle = '#5cf';
    c.lineWidth = 1.6;
    polyline(c, spec.wavelengths, spec.values, sx, sy);
    c.restore();
    this._drawLines(c, box, sx);
    c.textAlign = 'right';
    c.textBaseline = 'top';
    c.fillStyle = '#5cf';
    c.fillText('Doppler on', box.l + box.w - 4, box.t + 4);
    c.fillStyle = '#bbb';
    c.fillText('Doppler off', box.l + box.w - 4, box.t + 16);
    c.fillStyle = '#f66';
    c.fillText('▼ centroid', box.l + box.w - 4, box.t + 28);
  }

  /** Lines: dashed at the rest wavelength with the name, a triangle at the centroid. */
  _drawLines(c, box, sx) {
    const inside = (x) => x >= box.l && x <= box.l + box.w;
    const rows = [-Infinity, -Infinity]; // right end of the last label in each row
    c.lineWidth = 1;
    c.font = '10px sans-serif';
    for (const line of this.spec.lines || []) {
      const xr = sx(line.rest_nm);
      if (inside(xr)) {
        c.strokeStyle = 'rgba(255,200,80,0.55)';
        c.setLineDash([3, 3]);
        c.beginPath();
        c.moveTo(xr, box.t);
        c.lineTo(xr, box.t + box.h);
        c.stroke();
        c.setLineDash([]);
        // The name in the first row with room; none when both rows are taken.
        const tw = c.measureText(line.name).width;
        const k = rows.findIndex((end) => xr - tw / 2 > end + 4);
        if (k >= 0) {
          rows[k] = xr + tw / 2;
          c.fillStyle = '#fc6';
          c.textAlign = 'center';
          c.textBaseline = 'bottom';
          c.fillText(line.name, xr, box.t - 13 + k * 11);
        }
      }
      if (Number.isFinite(line.centroid_nm) && inside(sx(line.centroid_nm))) {
        const xc = sx(line.centroid_nm);
        c.fillStyle = '#f66';
        c.beginPath();
        c.moveTo(xc, box.t + 8);
        c.lineTo(xc - 4, box.t);
        c.lineTo(xc + 4, box.t);
        c.fill();
        c.textAlign = 'left';
        c.textBaseline = 'top';
        // The centroid's value only where the view is zoomed enough to read it.
        if (box.w / (this._range()[1] - this._range()[0]) > 20)
          c.fillText(line.centroid_nm.toFixed(3), xc + 5, box.t + 2);
      }
    }
  }
}

/** Draws a `trace` reply as small multiples into the container (one canvas per step). */
export function drawTrace(container, trace) {
  container.replaceChildren();
  const steps = trace.steps || [];
  if (steps.length === 0) return;
  const [x0, x1] = extent(...steps.map((s) => s.wavelengths));
  let [, y1] = extent(...steps.map((s) => s.values));
  if (!(y1 > 0)) y1 = 1;
  steps.forEach((s, i) => {
    const cv = document.createElement('canvas');
    cv.className = 'trace-cell';
    container.append(cv);
    const { c, w, h } = prepare(cv);
    const box = { l: 4, t: 14, w: w - 8, h: h - 18 };
    const { sx, sy } = axes(c, box, [x0, x1 > x0 ? x1 : x0 + 1], [0, y1 * 1.05], {
      xTicks: 3,
      yTicks: 2,
      labels: false,
    });
    c.strokeStyle = i === steps.length - 1 ? '#5cf' : '#8ac';
    c.lineWidth = 1;
    polyline(c, s.wavelengths, s.values, sx, sy);
    c.fillStyle = '#9aa3ad';
    c.font = '9px sans-serif';
    c.textAlign = 'left';
    c.textBaseline = 'top';
    c.fillText(`t ${fmtValue(s.t)}  v ${fmtValue(s.radial_velocity)}`, 3, 1);
  });
  const note = document.createElement('div');
  note.className = 'trace-note';
  note.textContent = `pixel (${trace.x}, ${trace.y}): ${steps.length} steps, ${x0.toFixed(1)}–${x1.toFixed(1)} nm, shared value axis 0–${fmtValue(y1)}`;
  container.append(note);
}

/** Draws a decoded colour-bar image into its canvas. */
export function drawColourbar(canvas, bitmap) {
  canvas.dataset.drawn = 'yes';
  canvas.width = bitmap.width;
  canvas.height = bitmap.height;
  canvas.getContext('2d').drawImage(bitmap, 0, 0);
}
