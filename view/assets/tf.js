// The transfer-function editor of HDR VolVis section 5 (Figs. 6 and 7): opacity knots over
// the log-count histogram, colour knots in a strip with an HSV picker, a fisheye data axis
// with several focus regions (Eq. 2), a linear or logarithmic opacity axis, alpha_g,
// rescaling, load and save. The pure helpers at the top need no DOM.

import { Fisheye, ValueAxis, normalize, valueAtNormalized } from './fisheye.js';
import { Throttle } from './net.js';

const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));

// ---- pure helpers (ports of tfedit/src/color.rs and tf.rs) ----

/** RGB in [0, 1] to HSV in [0, 1] (hue as a fraction of the circle). */
export function rgbToHsv([r, g, b]) {
  const max = Math.max(r, g, b);
  const min = Math.min(r, g, b);
  const delta = max - min;
  const s = max > 0 ? delta / max : 0;
  if (delta <= 0) return [0, s, max];
  let h;
  if (r === max) h = (g - b) / delta;
  else if (g === max) h = 2 + (b - r) / delta;
  else h = 4 + (r - g) / delta;
  h /= 6;
  if (h < 0) h += 1;
  return [h, s, max];
}

/** HSV (hue wraps) to RGB. */
export function hsvToRgb([h, s, v]) {
  const h6 = (((h % 1) + 1) % 1) * 6;
  const sector = Math.floor(h6);
  const f = h6 - sector;
  const p = v * (1 - s);
  const q = v * (1 - s * f);
  const t = v * (1 - s * (1 - f));
  return [
    [v, t, p],
    [q, v, p],
    [p, v, t],
    [p, q, v],
    [t, p, v],
    [v, p, q],
  ][Math.min(sector, 5)];
}

/** HSV interpolation along the shorter hue arc; a grey end takes the other end's hue. */
function hsvInterpolate(a, b, s) {
  const ha = rgbToHsv(a);
  const hb = rgbToHsv(b);
  if (ha[1] === 0) ha[0] = hb[0];
  if (hb[1] === 0) hb[0] = ha[0];
  let dh = hb[0] - ha[0];
  if (dh > 0.5) dh -= 1;
  else if (dh < -0.5) dh += 1;
  return hsvToRgb([ha[0] + dh * s, ha[1] + (hb[1] - ha[1]) * s, ha[2] + (hb[2] - ha[2]) * s]);
}

/**
 * Colour between two knots in the TF's colour space. `rgb`, `hsv` and `step` are exact;
 * `lab` and `diverging` are previewed with RGB interpolation (the server renders exactly).
 */
function interpolateColour(space, a, b, s) {
  if (s <= 0) return a;
  if (s >= 1) return b;
  if (space === 'hsv') return hsvInterpolate(a, b, s);
  if (space === 'step') return b;
  return [a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s, a[2] + (b[2] - a[2]) * s];
}

/** One segment of VTK's piecewise function (tfedit's segment_value), t in [0, 1). */
export function segmentValue(y1, y2, t, midpoint, sharpness) {
  const x =
    t < midpoint ? (0.5 * t) / midpoint : 0.5 + (0.5 * (t - midpoint)) / Math.max(1 - midpoint, 1e-300);
  if (sharpness > 0.99) return x < 0.5 ? y1 : y2;
  const lo = Math.min(y1, y2);
  const hi = Math.max(y1, y2);
  if (sharpness < 0.01) return clamp(y1 + (y2 - y1) * x, lo, hi);
  const e = 1 + sharpness * 10;
  let xs = x;
  if (x < 0.5) xs = 0.5 * Math.pow(x * 2, e);
  else if (x > 0.5) xs = 1 - 0.5 * Math.pow((1 - x) * 2, e);
  const ss = xs * xs;
  const sss = ss * xs;
  const slope = (1 - sharpness) * (y2 - y1);
  const v =
    (2 * sss - 3 * ss + 1) * y1 + (-2 * sss + 3 * ss) * y2 + (sss - 2 * ss + xs) * slope + (sss - ss) * slope;
  return clamp(v, lo, hi);
}

const axisCoord = (tf, v) => (tf.data_axis === 'log' ? Math.log10(v) : v);

/** Index of the first knot with coordinate > u (knots at or before u). */
function knotsAtOrBefore(knots, tf, u) {
  let i = 0;
  while (i < knots.length && axisCoord(tf, knots[i].x) <= u) i++;
  return i;
}

/** Knot opacity (before alpha_g) at data value v. */
export function evalOpacity(tf, v) {
  const k = tf.opacity;
  const u = axisCoord(tf, clamp(v, tf.domain[0], tf.domain[1]));
  const i = knotsAtOrBefore(k, tf, u);
  if (i === 0) return k[0].alpha;
  if (i === k.length) return k[k.length - 1].alpha;
  const u0 = axisCoord(tf, k[i - 1].x);
  const u1 = axisCoord(tf, k[i].x);
  return segmentValue(
    k[i - 1].alpha,
    k[i].alpha,
    (u - u0) / (u1 - u0),
    k[i - 1].midpoint ?? 0.5,
    k[i - 1].sharpness ?? 0,
  );
}

/** Colour at data value v. */
export function evalColour(tf, v) {
  const k = tf.color;
  const u = axisCoord(tf, clamp(v, tf.domain[0], tf.domain[1]));
  const i = knotsAtOrBefore(k, tf, u);
  if (i === 0) return k[0].rgb;
  if (i === k.length) return k[k.length - 1].rgb;
  const u0 = axisCoord(tf, k[i - 1].x);
  const u1 = axisCoord(tf, k[i].x);
  return interpolateColour(tf.color_space, k[i - 1].rgb, k[i].rgb, (u - u0) / (u1 - u0));
}

const css = (rgb, a = 1) =>
  `rgba(${rgb.map((c) => Math.round(clamp(c, 0, 1) * 255)).join(',')},${a})`;
const hex = (rgb) =>
  '#' + rgb.map((c) => Math.round(clamp(c, 0, 1) * 255).toString(16).padStart(2, '0')).join('');

/** Short number for axis labels. */
export function fmt(v) {
  if (v === 0) return '0';
  const a = Math.abs(v);
  if (a >= 1e4 || a < 1e-2) return v.toExponential(1).replace('e+', 'e');
  return String(Number(v.toPrecision(3)));
}

// ---- the editor ----

const PAD_L = 46;
const PAD_R = 12;
const PAD_T = 8;
const STRIP_H = 16;
const BAND_H = 46;
const HIT_PX = 7;
const DEFAULT_FOCUS = { width: 0.08, magnification: 4, transition: 0.03 };

const $ = (id) => document.getElementById(id);

export class TfEditor {
  /** send(obj) sends a message to the server. */
  constructor(send) {
    this.send = send;
    this.throttle = new Throttle(send);
    this.canvas = $('tf-canvas');
    this.ctx = this.canvas.getContext('2d');
    this.hsvCanvas = $('tf-hsv');
    this.channels = []; // {name, range, histogram, tf, regions, fisheyeOn, hsv, sel}
    this.channel = 0;
    this.axis = new ValueAxis('linear', 1e-4);
    this.drag = null;
    this.selRegion = -1;
    this._bindCanvas();
    this._bindTools();
    this._bindPicker();
    new ResizeObserver(() => this.draw()).observe(this.canvas);
  }

  get ch() {
    return this.channels[this.channel];
  }

  /** The current fisheye map (the identity when the fisheye is switched off). */
  get fisheye() {
    const ch = this.ch;
    if (!ch || !ch.fisheyeOn) return new Fisheye();
    return ch.fisheye;
  }

  setChannels(channels) {
    this.channels = channels.map((c) => ({
      name: c.name,
      range: c.range,
      histogram: c.histogram,
      tf: structuredClone(c.tf),
      confirmed: c.tf, // the server's last accepted TF, restored when an edit is refused
      regions: [],
      fisheye: new Fisheye(),
      fisheyeOn: true,
      sel: null, // {kind: 'opacity' | 'colour', i}
      hsv: null, // the selected colour knot's HSV (keeps the hue of greys)
    }));
    this.channel = Math.min(this.channel, Math.max(0, channels.length - 1));
    this.selRegion = -1;
    const tabs = $('tf-tabs');
    tabs.replaceChildren(
      ...this.channels.map((c, i) => {
        const b = document.createElement('button');
        b.textContent = c.name || `channel ${i}`;
        b.addEventListener('click', () => this.selectChannel(i));
        return b;
      }),
    );
    this.selectChannel(this.channel);
  }

  selectChannel(i) {
    this.channel = i;
    [...$('tf-tabs').children].forEach((b, j) => b.classList.toggle('active', j === i));
    this.selRegion = -1;
    this._syncTools();
    this.draw();
  }

  /** A TF from the server (`tf` reply); ignored for the channel being dragged. */
  setTf(channel, tf) {
    const ch = this.channels[channel];
    if (!ch) return;
    ch.confirmed = tf;
    if (this.drag && channel === this.channel) return;
    ch.tf = structuredClone(tf);
    if (ch.sel) {
      const list = ch.sel.kind === 'opacity' ? tf.opacity : tf.color;
      if (ch.sel.i >= list.length) ch.sel = null;
    }
    if (channel === this.channel) {
      this._syncTools();
      this.draw();
    }
  }

  /** The server refused the last `tf`: go back to the TF it last accepted. */
  revert() {
    for (const [i, ch] of this.channels.entries()) if (ch.confirmed) this.setTf(i, ch.confirmed);
  }

  // ---- geometry ----

  _geom() {
    const w = this.canvas.clientWidth;
    const h = this.canvas.clientHeight;
    const curveH = h - PAD_T - STRIP_H - 4 - BAND_H;
    const curveTop = PAD_T;
    const stripTop = curveTop + curveH + 4;
    const bandTop = stripTop + STRIP_H;
    return { w, h, L: PAD_L, W: w - PAD_L - PAD_R, curveTop, curveH, stripTop, bandTop };
  }

  _sx(g, t) {
    return g.L + this.fisheye.forward(t) * g.W;
  }
  _tAt(g, px) {
    return this.fisheye.inverse((px - g.L) / g.W);
  }
  _sy(g, alpha) {
    return g.curveTop + (1 - this.axis.forward(alpha)) * g.curveH;
  }
  _alphaAt(g, py) {
    const y = 1 - (py - g.curveTop) / g.curveH;
    // On the log axis the bottom edge stands for 0 (below the floor).
    if (this.axis.kind === 'log' && y <= 0) return 0;
    return this.axis.inverse(y);
  }
  _tOf(x) {
    const tf = this.ch.tf;
    return normalize(x, tf.domain, tf.data_axis);
  }
  _xOf(t) {
    const tf = this.ch.tf;
    return valueAtNormalized(t, tf.domain, tf.data_axis);
  }

  /** Page coordinates of opacity or colour knot i (test hook). */
  knotScreenPos(kind, i) {
    const g = this._geom();
    const tf = this.ch.tf;
    const rect = this.canvas.getBoundingClientRect();
    const k = kind === 'opacity' ? tf.opacity[i] : tf.color[i];
    if (!k) throw new Error(`no ${kind} knot ${i}`);
    const x = this._sx(g, this._tOf(k.x));
    const y = kind === 'opacity' ? this._sy(g, k.alpha) : g.stripTop + STRIP_H / 2;
    return { x: rect.left + window.scrollX + x, y: rect.top + window.scrollY + y };
  }

  // ---- fisheye regions ----

  /** Replaces the regions if they make a valid map; returns whether they did. */
  _setRegions(regions) {
    let fe;
    try {
      fe = new Fisheye(regions);
    } catch {
      return false;
    }
    this.ch.regions = fe.regions;
    this.ch.fisheye = fe;
    return true;
  }

  /** Adds a focus region (test hook; throws for an invalid one). Returns its index. */
  addFocus(center, width, magnification, transition) {
    const fe = new Fisheye([...this.ch.regions, { center, width, magnification, transition }]);
    this.ch.regions = fe.regions;
    this.ch.fisheye = fe;
    this.ch.fisheyeOn = true;
    this.selRegion = fe.regions.findIndex((r) => r.center === center);
    this._syncTools();
    this.draw();
    return this.selRegion;
  }

  /** Adds a region near t, shrinking it until it fits; false if there is no room. */
  _addFocusNear(t) {
    for (let s = 1; s > 0.05; s *= 0.7) {
      try {
        const d = DEFAULT_FOCUS;
        this.addFocus(t, d.width * s, d.magnification, d.transition * s);
        return true;
      } catch {
        // try a smaller one
      }
    }
    this._message('no room for another focus region there');
    return false;
  }

  /** The middle of the widest stretch of axis not covered by a region. */
  _freeSpot() {
    let best = 0.5;
    let bestLen = -1;
    let cursor = 0;
    const rs = this.ch.regions;
    for (let i = 0; i <= rs.length; i++) {
      const end = i < rs.length ? rs[i].center - rs[i].width / 2 - rs[i].transition : 1;
      if (end - cursor > bestLen) {
        bestLen = end - cursor;
        best = (cursor + end) / 2;
      }
      if (i < rs.length) cursor = rs[i].center + rs[i].width / 2 + rs[i].transition;
    }
    return best;
  }

  _message(text) {
    $('tf-note').textContent = text;
  }

  // ---- sending ----

  _sendTf(final) {
    const msg = { type: 'tf', channel: this.channel, tf: structuredClone(this.ch.tf) };
    this.throttle.push(msg);
    if (final) this.throttle.flush();
  }

  // ---- mouse on the editor canvas ----

  _hit(g, px, py) {
    const tf = this.ch.tf;
    const near = (x, y) => Math.hypot(px - x, py - y) <= HIT_PX;
    if (py >= g.stripTop - 3 && py <= g.stripTop + STRIP_H + 3) {
      for (let i = tf.color.length - 1; i >= 0; i--)
        if (Math.abs(px - this._sx(g, this._tOf(tf.color[i].x))) <= HIT_PX)
          return { kind: 'colour', i };
      return { kind: 'strip' };
    }
    if (py < g.stripTop) {
      for (let i = tf.opacity.length - 1; i >= 0; i--) {
        const k = tf.opacity[i];
        if (near(this._sx(g, this._tOf(k.x)), this._sy(g, k.alpha))) return { kind: 'opacity', i };
      }
      return { kind: 'curve' };
    }
    if (this.ch.fisheyeOn) {
      const rs = this.ch.regions;
      for (let j = 0; j < rs.length; j++) {
        const r = rs[j];
        const xs = [
          ['handle', r.center],
          ['edge-lo', r.center - r.width / 2],
          ['edge-hi', r.center + r.width / 2],
          ['trans-lo', r.center - r.width / 2 - r.transition],
          ['trans-hi', r.center + r.width / 2 + r.transition],
        ];
        for (const [part, t] of xs)
          if (Math.abs(px - this._sx(g, t)) <= 5) return { kind: 'region', j, part };
      }
      for (let j = 0; j < rs.length; j++) {
        const r = rs[j];
        const t = this._tAt(g, px);
        if (Math.abs(t - r.center) <= r.width / 2 + r.transition) return { kind: 'region', j, part: 'handle' };
      }
    }
    return { kind: 'band' };
  }

  _bindCanvas() {
    const el = this.canvas;
    const pos = (ev) => {
      const r = el.getBoundingClientRect();
      return [ev.clientX - r.left, ev.clientY - r.top];
    };
    el.addEventListener('contextmenu', (ev) => {
      ev.preventDefault();
      if (!this.ch) return;
      const [px, py] = pos(ev);
      this._delete(this._hit(this._geom(), px, py));
    });
    el.addEventListener('dblclick', (ev) => {
      if (!this.ch) return;
      const [px, py] = pos(ev);
      this._delete(this._hit(this._geom(), px, py));
    });
    el.addEventListener('pointerdown', (ev) => {
      if (!this.ch || ev.button !== 0) return;
      const g = this._geom();
      const [px, py] = pos(ev);
      const hit = this._hit(g, px, py);
      const tf = this.ch.tf;
      if (ev.ctrlKey || ev.metaKey) {
        this._addFocusNear(this._tAt(g, px));
        return;
      }
      el.setPointerCapture(ev.pointerId);
      if (hit.kind === 'curve') {
        const x = this._xOf(this._tAt(g, px));
        const i = tf.opacity.findIndex((k) => k.x > x);
        if (i <= 0) return; // outside the end knots
        tf.opacity.splice(i, 0, { x, alpha: clamp(this._alphaAt(g, py), 0, 1) });
        this.ch.sel = { kind: 'opacity', i };
        this.drag = { kind: 'opacity', i, changed: true };
        this._sendTf(false);
      } else if (hit.kind === 'strip') {
        const x = this._xOf(this._tAt(g, px));
        const i = tf.color.findIndex((k) => k.x > x);
        if (i <= 0) return;
        tf.color.splice(i, 0, { x, rgb: evalColour(tf, x).slice() });
        this._selectColour(i);
        this.drag = { kind: 'colour', i, changed: true };
        this._sendTf(false);
      } else if (hit.kind === 'opacity') {
        this.ch.sel = { kind: 'opacity', i: hit.i };
        this.drag = { kind: 'opacity', i: hit.i };
      } else if (hit.kind === 'colour') {
        this._selectColour(hit.i);
        this.drag = { kind: 'colour', i: hit.i };
      } else if (hit.kind === 'region') {
        this.selRegion = hit.j;
        // Map mouse positions with the map as it was when the drag began: the map changes
        // as the region moves, and using the live one would feed back.
        this.drag = {
          kind: 'region',
          j: hit.j,
          part: hit.part,
          map: this.fisheye,
          t0: this._tAt(g, px),
          r0: { ...this.ch.regions[hit.j] },
        };
      }
      this._syncTools();
      this.draw();
    });
    el.addEventListener('pointermove', (ev) => {
      if (!this.drag) return;
      const g = this._geom();
      const [px, py] = pos(ev);
      if (this._dragTo(g, px, py)) this.draw();
    });
    const end = () => {
      const d = this.drag;
      if (!d) return;
      this.drag = null;
      // A click that selects a knot without moving it changes nothing.
      if (d.changed) this._sendTf(true);
      this._syncTools();
      this.draw();
    };
    el.addEventListener('pointerup', end);
    el.addEventListener('pointercancel', end);
    el.addEventListener(
      'wheel',
      (ev) => {
        if (!this.ch) return;
        const g = this._geom();
        const [px, py] = pos(ev);
        const hit = this._hit(g, px, py);
        if (hit.kind !== 'region' && !(py < g.stripTop + STRIP_H && this._regionAt(g, px) >= 0)) return;
        const j = hit.kind === 'region' ? hit.j : this._regionAt(g, px);
        ev.preventDefault();
        const rs = this.ch.regions.map((r) => ({ ...r }));
        rs[j].magnification = Math.max(1.01, rs[j].magnification * Math.exp(-ev.deltaY * 0.002));
        this.selRegion = j;
        if (this._setRegions(rs)) {
          this._syncTools();
          this.draw();
        }
      },
      { passive: false },
    );
  }

  _regionAt(g, px) {
    const t = this._tAt(g, px);
    return this.ch.regions.findIndex((r) => Math.abs(t - r.center) <= r.width / 2 + r.transition);
  }

  /** Applies a drag to (px, py); returns whether anything changed. */
  _dragTo(g, px, py) {
    const d = this.drag;
    const tf = this.ch.tf;
    if (d.kind === 'opacity' || d.kind === 'colour') {
      const list = d.kind === 'opacity' ? tf.opacity : tf.color;
      const k = list[d.i];
      // End knots stay at the domain ends (they still move in alpha).
      if (d.i > 0 && d.i < list.length - 1) {
        const lo = list[d.i - 1].x;
        const hi = list[d.i + 1].x;
        const eps = (hi - lo) * 1e-6;
        k.x = clamp(this._xOf(this._tAt(g, px)), lo + eps, hi - eps);
      }
      if (d.kind === 'opacity') k.alpha = clamp(this._alphaAt(g, py), 0, 1);
      d.changed = true;
      this._sendTf(false);
      return true;
    }
    if (d.kind === 'region') {
      const dt = d.map.inverse((px - g.L) / g.W) - d.t0;
      const rs = this.ch.regions.map((r) => ({ ...r }));
      const r = { ...d.r0 };
      const tNow = d.t0 + dt;
      if (d.part === 'handle') r.center = clamp(d.r0.center + dt, 0, 1);
      else if (d.part.startsWith('edge')) r.width = Math.max(0.002, 2 * Math.abs(tNow - r.center));
      else r.transition = Math.max(0, Math.abs(tNow - r.center) - r.width / 2);
      // Regions cannot pass each other (overlaps are refused), so the index stays.
      rs[d.j] = r;
      if (!this._setRegions(rs)) return false;
      this._syncTools();
      return true;
    }
    return false;
  }

  _delete(hit) {
    const tf = this.ch.tf;
    if (hit.kind === 'opacity' || hit.kind === 'colour') {
      const list = hit.kind === 'opacity' ? tf.opacity : tf.color;
      if (hit.i === 0 || hit.i === list.length - 1) {
        this._message('the end knots stay (move them in alpha instead)');
        return;
      }
      list.splice(hit.i, 1);
      this.ch.sel = null;
      this._sendTf(true);
    } else if (hit.kind === 'region') {
      this._setRegions(this.ch.regions.filter((_, j) => j !== hit.j));
      this.selRegion = -1;
    } else return;
    this._syncTools();
    this.draw();
  }

  _selectColour(i) {
    this.ch.sel = { kind: 'colour', i };
    this.ch.hsv = rgbToHsv(this.ch.tf.color[i].rgb);
    this.drawPicker();
  }

  // ---- the toolbar ----

  _bindTools() {
    $('tf-axis').addEventListener('change', () => this.setValueAxis($('tf-axis').value, this.axis.floor));
    $('tf-floor').addEventListener('change', () => {
      const f = Number($('tf-floor').value);
      if (f > 0 && f < 1) this.setValueAxis(this.axis.kind, f);
      else this._message('the floor must be in (0, 1)');
    });
    const ag = $('tf-alphag');
    ag.addEventListener('input', () => {
      this.ch.tf.alpha_g = Math.pow(10, Number(ag.value));
      $('tf-alphag-val').textContent = fmt(this.ch.tf.alpha_g);
      this._sendTf(false);
    });
    ag.addEventListener('change', () => this._sendTf(true));
    $('tf-add-focus').addEventListener('click', () => this.ch && this._addFocusNear(this._freeSpot()));
    $('tf-del-focus').addEventListener('click', () => {
      if (this.selRegion >= 0) this._delete({ kind: 'region', j: this.selRegion });
    });
    $('tf-fisheye-on').addEventListener('change', () => {
      this.ch.fisheyeOn = $('tf-fisheye-on').checked;
      this.draw();
    });
    const mag = $('tf-mag');
    mag.addEventListener('input', () => this._editRegion({ magnification: Math.pow(10, Number(mag.value)) }));
    const tr = $('tf-trans');
    tr.addEventListener('input', () => this._editRegion({ transition: Number(tr.value) }));
    $('tf-range-data').addEventListener('click', () =>
      this.send({ type: 'tf_range', channel: this._rangeChannel(), range: 'data' }),
    );
    $('tf-range-apply').addEventListener('click', () => {
      const lo = Number($('tf-lo').value);
      const hi = Number($('tf-hi').value);
      if (!(Number.isFinite(lo) && Number.isFinite(hi) && lo < hi)) {
        this._message('the range needs two numbers lo < hi');
        return;
      }
      this.send({ type: 'tf_range', channel: this._rangeChannel(), range: [lo, hi] });
    });
    $('tf-file').addEventListener('change', async () => {
      const file = $('tf-file').files[0];
      if (!file) return;
      this.send({ type: 'tf_load', channel: this.channel, text: await file.text() });
      $('tf-file').value = '';
    });
    $('tf-export').addEventListener('click', () =>
      this.send({ type: 'tf_export', channel: this.channel, format: $('tf-format').value }),
    );
  }

  _rangeChannel() {
    return $('tf-range-all').checked ? null : this.channel;
  }

  _editRegion(change) {
    const j = this.selRegion;
    if (j < 0) return;
    const rs = this.ch.regions.map((r) => ({ ...r }));
    Object.assign(rs[j], change);
    if (this._setRegions(rs)) this._syncTools();
    else this._message('that leaves no room for the context (M_min <= 0) or overlaps');
    this.draw();
  }

  setValueAxis(kind, floor) {
    this.axis = new ValueAxis(kind, floor);
    $('tf-axis').value = kind;
    $('tf-floor').value = String(floor);
    this.draw();
  }

  /** The offer of a `tf_text` reply as a download. */
  download(msg) {
    const blob = new Blob([msg.text], { type: 'application/json' });
    const a = document.createElement('a');
    a.href = URL.createObjectURL(blob);
    const name = (this.channels[msg.channel]?.tf.name || 'transfer-function').replace(/[^\w-]+/g, '_');
    a.download = `${name}${msg.format === 'paraview' ? '.paraview' : ''}.json`;
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  }

  /** Puts the current state into the toolbar's inputs. */
  _syncTools() {
    const ch = this.ch;
    if (!ch) return;
    const tf = ch.tf;
    $('tf-alphag').value = String(Math.log10(Math.max(tf.alpha_g, 1e-4)));
    $('tf-alphag-val').textContent = fmt(tf.alpha_g);
    if (document.activeElement !== $('tf-lo')) $('tf-lo').value = String(tf.domain[0]);
    if (document.activeElement !== $('tf-hi')) $('tf-hi').value = String(tf.domain[1]);
    $('tf-fisheye-on').checked = ch.fisheyeOn;
    $('tf-mmin').textContent = this.fisheye.mMin.toFixed(3);
    const r = ch.regions[this.selRegion];
    $('tf-mag').disabled = !r;
    $('tf-trans').disabled = !r;
    $('tf-del-focus').disabled = !r;
    if (r) {
      $('tf-mag').value = String(Math.log10(r.magnification));
      $('tf-trans').value = String(r.transition);
    }
    $('tf-mag-val').textContent = r ? r.magnification.toFixed(2) : '–';
    $('tf-trans-val').textContent = r ? r.transition.toFixed(3) : '–';
    const sel = ch.sel;
    let text = `domain ${fmt(tf.domain[0])} .. ${fmt(tf.domain[1])} (${tf.data_axis}, ${tf.color_space})`;
    if (sel) {
      const k = sel.kind === 'opacity' ? tf.opacity[sel.i] : tf.color[sel.i];
      text =
        sel.kind === 'opacity'
          ? `opacity knot ${sel.i}: x = ${fmt(k.x)}, alpha = ${k.alpha.toPrecision(3)}`
          : `colour knot ${sel.i}: x = ${fmt(k.x)}, ${hex(k.rgb)}`;
    }
    $('tf-note').textContent = text;
    this.drawPicker();
  }

  // ---- the HSV picker: SV square and hue bar ----

  _bindPicker() {
    const el = this.hsvCanvas;
    const apply = (ev) => {
      const ch = this.ch;
      if (!ch || !ch.sel || ch.sel.kind !== 'colour') return;
      const r = el.getBoundingClientRect();
      const x = ev.clientX - r.left;
      const y = ev.clientY - r.top;
      const sq = r.height;
      const hsv = ch.hsv;
      if (this.pickerPart === 'hue') hsv[0] = clamp(y / sq, 0, 0.9999);
      else {
        hsv[1] = clamp(x / sq, 0, 1);
        hsv[2] = clamp(1 - y / sq, 0, 1);
      }
      ch.tf.color[ch.sel.i].rgb = hsvToRgb(hsv);
      this._sendTf(false);
      this._syncTools();
      this.draw();
    };
    el.addEventListener('pointerdown', (ev) => {
      const r = el.getBoundingClientRect();
      this.pickerPart = ev.clientX - r.left > r.height + 4 ? 'hue' : 'sv';
      el.setPointerCapture(ev.pointerId);
      this.picking = true;
      apply(ev);
    });
    el.addEventListener('pointermove', (ev) => this.picking && apply(ev));
    el.addEventListener('pointerup', () => {
      if (!this.picking) return;
      this.picking = false;
      if (this.ch?.sel?.kind === 'colour') this._sendTf(true);
    });
    $('tf-hex').addEventListener('change', () => {
      const ch = this.ch;
      const m = /^#?([0-9a-f]{6})$/i.exec($('tf-hex').value.trim());
      if (!ch?.sel || ch.sel.kind !== 'colour' || !m) return;
      const n = parseInt(m[1], 16);
      const rgb = [(n >> 16) & 255, (n >> 8) & 255, n & 255].map((c) => c / 255);
      ch.tf.color[ch.sel.i].rgb = rgb;
      ch.hsv = rgbToHsv(rgb);
      this._sendTf(true);
      this._syncTools();
      this.draw();
    });
  }

  drawPicker() {
    const el = this.hsvCanvas;
    const dpr = window.devicePixelRatio || 1;
    const w = el.clientWidth;
    const h = el.clientHeight;
    el.width = Math.round(w * dpr);
    el.height = Math.round(h * dpr);
    const c = el.getContext('2d');
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    c.clearRect(0, 0, w, h);
    const ch = this.ch;
    const active = ch && ch.sel && ch.sel.kind === 'colour';
    $('tf-hex').disabled = !active;
    if (!active) {
      c.fillStyle = '#777';
      c.font = '11px sans-serif';
      c.fillText('select a colour knot', 6, h / 2);
      $('tf-hex').value = '';
      return;
    }
    const hsv = ch.hsv;
    const sq = h;
    // SV square: white-to-hue horizontally, then black vertically.
    const gx = c.createLinearGradient(0, 0, sq, 0);
    gx.addColorStop(0, '#fff');
    gx.addColorStop(1, css(hsvToRgb([hsv[0], 1, 1])));
    c.fillStyle = gx;
    c.fillRect(0, 0, sq, sq);
    const gy = c.createLinearGradient(0, 0, 0, sq);
    gy.addColorStop(0, 'rgba(0,0,0,0)');
    gy.addColorStop(1, '#000');
    c.fillStyle = gy;
    c.fillRect(0, 0, sq, sq);
    c.strokeStyle = hsv[2] > 0.5 ? '#000' : '#fff';
    c.beginPath();
    c.arc(hsv[1] * sq, (1 - hsv[2]) * sq, 4, 0, 2 * Math.PI);
    c.stroke();
    // Hue bar.
    const bx = sq + 6;
    const bw = Math.min(18, w - bx);
    const gh = c.createLinearGradient(0, 0, 0, sq);
    for (let i = 0; i <= 6; i++) gh.addColorStop(i / 6, css(hsvToRgb([i / 6, 1, 1])));
    c.fillStyle = gh;
    c.fillRect(bx, 0, bw, sq);
    c.strokeStyle = '#fff';
    c.strokeRect(bx - 1, hsv[0] * sq - 2, bw + 2, 4);
    if (document.activeElement !== $('tf-hex')) $('tf-hex').value = hex(ch.tf.color[ch.sel.i].rgb);
  }

  // ---- drawing the editor ----

  draw() {
    const el = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const g = this._geom();
    if (el.width !== Math.round(g.w * dpr) || el.height !== Math.round(g.h * dpr)) {
      el.width = Math.round(g.w * dpr);
      el.height = Math.round(g.h * dpr);
    }
    const c = this.ctx;
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    c.clearRect(0, 0, g.w, g.h);
    c.fillStyle = '#15181d';
    c.fillRect(g.L, g.curveTop, g.W, g.curveH);
    if (!this.ch) return;
    this._drawHistogram(c, g);
    this._drawValueGrid(c, g);
    this._drawCurve(c, g);
    this._drawStrip(c, g);
    this._drawBand(c, g);
  }

  _drawHistogram(c, g) {
    const hist = this.ch.histogram;
    if (!hist || !hist.counts || hist.counts.length === 0) return;
    const n = hist.counts.length;
    const maxLog = Math.log10(1 + Math.max(...hist.counts));
    if (maxLog <= 0) return;
    c.fillStyle = 'rgba(150,160,175,0.28)';
    for (let i = 0; i < n; i++) {
      if (hist.counts[i] <= 0) continue;
      const v0 = hist.lo + ((hist.hi - hist.lo) * i) / n;
      const v1 = hist.lo + ((hist.hi - hist.lo) * (i + 1)) / n;
      const x0 = this._sx(g, this._tOf(v0));
      const x1 = this._sx(g, this._tOf(v1));
      const hh = (Math.log10(1 + hist.counts[i]) / maxLog) * g.curveH;
      c.fillRect(x0, g.curveTop + g.curveH - hh, Math.max(1, x1 - x0), hh);
    }
  }

  _drawValueGrid(c, g) {
    c.font = '10px sans-serif';
    c.textAlign = 'right';
    c.textBaseline = 'middle';
    const ticks = [];
    if (this.axis.kind === 'log') {
      for (let e = 0; Math.pow(10, -e) >= this.axis.floor * 0.999; e++) ticks.push(Math.pow(10, -e));
    } else ticks.push(0, 0.25, 0.5, 0.75, 1);
    for (const v of ticks) {
      const y = this._sy(g, v);
      c.strokeStyle = 'rgba(255,255,255,0.08)';
      c.beginPath();
      c.moveTo(g.L, y);
      c.lineTo(g.L + g.W, y);
      c.stroke();
      c.fillStyle = '#9aa3ad';
      c.fillText(this.axis.kind === 'log' ? (v === 1 ? '1' : `1e${Math.round(Math.log10(v))}`) : String(v), g.L - 4, y);
    }
    c.save();
    c.translate(10, g.curveTop + g.curveH / 2);
    c.rotate(-Math.PI / 2);
    c.textAlign = 'center';
    c.fillText(`opacity (${this.axis.kind})`, 0, 0);
    c.restore();
  }

  _drawCurve(c, g) {
    const tf = this.ch.tf;
    const bottom = g.curveTop + g.curveH;
    const pts = [];
    for (let px = 0; px <= g.W; px++) {
      const v = this._xOf(this._tAt(g, g.L + px));
      const a = evalOpacity(tf, v);
      pts.push([g.L + px, this._sy(g, a), v]);
    }
    // Fill under the curve with the TF's colour.
    for (const [x, y, v] of pts) {
      c.fillStyle = css(evalColour(tf, v), 0.35);
      c.fillRect(x, y, 1, bottom - y);
    }
    c.strokeStyle = '#e8e8e8';
    c.lineWidth = 1.5;
    c.beginPath();
    pts.forEach(([x, y], i) => (i ? c.lineTo(x, y) : c.moveTo(x, y)));
    c.stroke();
    c.lineWidth = 1;
    tf.opacity.forEach((k, i) => {
      const x = this._sx(g, this._tOf(k.x));
      const y = this._sy(g, k.alpha);
      const sel = this.ch.sel && this.ch.sel.kind === 'opacity' && this.ch.sel.i === i;
      c.fillStyle = sel ? '#ffcc33' : '#fff';
      c.strokeStyle = '#000';
      c.beginPath();
      c.arc(x, y, sel ? 5 : 4, 0, 2 * Math.PI);
      c.fill();
      c.stroke();
    });
  }

  _drawStrip(c, g) {
    const tf = this.ch.tf;
    for (let px = 0; px <= g.W; px++) {
      c.fillStyle = css(evalColour(tf, this._xOf(this._tAt(g, g.L + px))));
      c.fillRect(g.L + px, g.stripTop, 1, STRIP_H);
    }
    const xs = tf.color.map((k) => this._sx(g, this._tOf(k.x)));
    xs.forEach((x, i) => {
      // Markers as wide as the gap to the neighbours allows (dense maps have many knots).
      const gap = Math.min(i > 0 ? x - xs[i - 1] : Infinity, i + 1 < xs.length ? xs[i + 1] - x : Infinity);
      const half = clamp((gap - 1) / 2, 1.5, 4);
      const sel = this.ch.sel && this.ch.sel.kind === 'colour' && this.ch.sel.i === i;
      c.fillStyle = css(tf.color[i].rgb);
      c.strokeStyle = sel ? '#ffcc33' : 'rgba(255,255,255,0.8)';
      c.lineWidth = sel ? 2 : 1;
      c.fillRect(x - half, g.stripTop + 1, 2 * half, STRIP_H - 2);
      c.strokeRect(x - half, g.stripTop + 1, 2 * half, STRIP_H - 2);
    });
    c.lineWidth = 1;
  }

  /** The data axis band: tick labels, focus regions (Fig. 6a) and M(t) (Fig. 6b). */
  _drawBand(c, g) {
    const fe = this.fisheye;
    const top = g.bandTop;
    const profTop = top + 14;
    const profH = BAND_H - 16;
    c.font = '10px sans-serif';
    c.textBaseline = 'top';
    c.fillStyle = '#9aa3ad';
    // Data ticks at evenly spaced window positions: their labels show the nonlinearity.
    for (let i = 0; i <= 8; i++) {
      const x = g.L + (i / 8) * g.W;
      c.textAlign = i === 0 ? 'left' : i === 8 ? 'right' : 'center';
      c.fillText(fmt(this._xOf(fe.inverse(i / 8))), x, top + 2);
      c.fillRect(x, top, 1, 2);
    }
    const rs = this.ch.fisheyeOn ? this.ch.regions : [];
    const mMax = Math.max(1.5, ...rs.map((r) => r.magnification));
    const my = (m) => profTop + profH - (m / mMax) * profH;
    rs.forEach((r, j) => {
      const sel = j === this.selRegion;
      const xtr0 = this._sx(g, r.center - r.width / 2 - r.transition);
      const xtr1 = this._sx(g, r.center + r.width / 2 + r.transition);
      const xc0 = this._sx(g, r.center - r.width / 2);
      const xc1 = this._sx(g, r.center + r.width / 2);
      c.fillStyle = 'rgba(60,200,90,0.18)';
      c.fillRect(xtr0, profTop, xtr1 - xtr0, profH);
      c.fillStyle = sel ? 'rgba(80,230,110,0.5)' : 'rgba(60,200,90,0.35)';
      c.fillRect(xc0, profTop, xc1 - xc0, profH);
      c.fillStyle = '#4c4';
      c.fillRect(xc0 - 1, profTop, 2, profH);
      c.fillRect(xc1 - 1, profTop, 2, profH);
      const xh = this._sx(g, r.center);
      c.fillStyle = sel ? '#ffcc33' : '#8f8';
      c.beginPath();
      c.moveTo(xh, profTop + profH - 8);
      c.lineTo(xh - 5, profTop + profH);
      c.lineTo(xh + 5, profTop + profH);
      c.fill();
      c.textAlign = 'center';
      c.fillStyle = '#cfc';
      c.fillText(`M_c ${r.magnification.toFixed(1)}`, xh, profTop);
    });
    // The magnification profile and the M = 1 line.
    c.strokeStyle = 'rgba(255,255,255,0.25)';
    c.setLineDash([3, 3]);
    c.beginPath();
    c.moveTo(g.L, my(1));
    c.lineTo(g.L + g.W, my(1));
    c.stroke();
    c.setLineDash([]);
    c.strokeStyle = '#6f6';
    c.beginPath();
    for (let px = 0; px <= g.W; px++) {
      const y = my(fe.magnification(this._tAt(g, g.L + px)));
      px ? c.lineTo(g.L + px, y) : c.moveTo(g.L + px, y);
    }
    c.stroke();
    c.textAlign = 'right';
    c.textBaseline = 'middle';
    c.fillStyle = '#9aa3ad';
    c.fillText('M_min', g.L - 4, profTop + 6);
    c.fillText(fe.mMin.toFixed(3), g.L - 4, profTop + 18);
  }
}
