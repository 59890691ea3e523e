// Pure maps of the transfer-function editor (no DOM: node tests import this file).
//
// - `Fisheye`: the 1D focus+context magnification of the normalised data axis, HDR VolVis
//   section 5, Eq. 2 (Figs. 6 and 7). A port of tfedit/src/axis.rs, same numbers.
// - `ValueAxis`: the linear or logarithmic opacity/colour axis with a floor.
// - `normalize` / `valueAtNormalized`: data value <-> normalised position t in [0, 1] on a
//   linear or log10 data axis (tfedit's TransferFunction::normalized).

const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));

/** Index of the first element for which `pred` is false (Rust's `partition_point`). */
function partitionPoint(arr, pred) {
  let lo = 0;
  let hi = arr.length;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (pred(arr[mid])) lo = mid + 1;
    else hi = mid;
  }
  return lo;
}

/**
 * One piece of the magnification profile: on [t0, t1] the magnification goes linearly from
 * m0 to m1; s0 is the window position at t0.
 */
class Piece {
  constructor(t0, t1, m0, m1, s0) {
    Object.assign(this, { t0, t1, m0, m1, s0 });
  }
  forward(t) {
    const d = clamp(t - this.t0, 0, this.t1 - this.t0);
    const k = (this.m1 - this.m0) / (this.t1 - this.t0);
    return this.s0 + d * (this.m0 + 0.5 * k * d);
  }
  get s1() {
    return this.s0 + 0.5 * (this.m0 + this.m1) * (this.t1 - this.t0);
  }
  inverse(s) {
    const len = this.t1 - this.t0;
    const ds = Math.max(s - this.s0, 0);
    const k = (this.m1 - this.m0) / len;
    // Solve 0.5 k d^2 + m0 d - ds = 0 in the cancellation-free form.
    const disc = Math.max(this.m0 * this.m0 + 2 * k * ds, 0);
    const d = (2 * ds) / (this.m0 + Math.sqrt(disc));
    return this.t0 + clamp(d, 0, len);
  }
}

/** [lo, hi] support of a focus region: R_c plus its transition on each side. */
function support(r) {
  const h = 0.5 * r.width + r.transition;
  return [r.center - h, r.center + h];
}

/**
 * The fisheye map of the normalised data axis t in [0, 1] onto the window x in [0, 1].
 * Regions: {center, width, magnification, transition} in normalised units. Throws an Error
 * (with the same conditions as axis.rs) for invalid or overlapping regions, or when M_min
 * would be <= 0.
 */
export class Fisheye {
  constructor(regions = []) {
    regions = regions.map((r, i) => {
      const c = {
        center: r.center,
        width: r.width,
        magnification: r.magnification,
        transition: r.transition ?? 0,
      };
      const vals = [c.center, c.width, c.magnification, c.transition];
      if (!vals.every((v) => typeof v === 'number' && Number.isFinite(v)))
        throw new Error(`focus region ${i}: numbers must be finite`);
      if (c.center < 0 || c.center > 1)
        throw new Error(`focus region ${i}: centre ${c.center} is outside [0, 1]`);
      if (c.width <= 0) throw new Error(`focus region ${i}: width ${c.width} must be > 0`);
      if (c.magnification <= 1)
        throw new Error(`focus region ${i}: magnification ${c.magnification} must be > 1`);
      if (c.transition < 0)
        throw new Error(`focus region ${i}: transition ${c.transition} must be >= 0`);
      return c;
    });
    regions.sort((a, b) => a.center - b.center);
    for (let i = 1; i < regions.length; i++) {
      if (support(regions[i - 1])[1] > support(regions[i])[0])
        throw new Error(
          `focus regions centred at ${regions[i - 1].center} and ${regions[i].center} overlap`,
        );
    }
    this._regions = regions;
    if (regions.length === 0) {
      this._mMin = 1;
      this._pieces = [new Piece(0, 1, 1, 1, 0)];
      return;
    }
    // Profile pieces with magnification a + b * M_min at each end (b = 1 in the context).
    const sym = [];
    const push = (t0, t1, m0, m1) => {
      // Clip to [0, 1], interpolating the symbolic magnification linearly.
      const c0 = Math.max(t0, 0);
      const c1 = Math.min(t1, 1);
      if (c1 <= c0) return;
      const at = (t) => {
        const f = t1 > t0 ? (t - t0) / (t1 - t0) : 0;
        return [m0[0] + (m1[0] - m0[0]) * f, m0[1] + (m1[1] - m0[1]) * f];
      };
      const p = at(c0);
      const q = at(c1);
      sym.push({ t0: c0, t1: c1, a0: p[0], b0: p[1], a1: q[0], b1: q[1] });
    };
    const ctx = [0, 1];
    let cursor = 0;
    for (const r of regions) {
      const mc = [r.magnification, 0];
      const h = 0.5 * r.width;
      const [lo, hi] = support(r);
      push(cursor, lo, ctx, ctx);
      push(lo, r.center - h, ctx, mc);
      push(r.center - h, r.center + h, mc, mc);
      push(r.center + h, hi, mc, ctx);
      cursor = hi;
    }
    push(cursor, 1, ctx, ctx);
    // Eq. 2: the sum over pieces of the mean magnification times the length is 1.
    let a = 0;
    let b = 0;
    for (const p of sym) {
      const len = p.t1 - p.t0;
      a += 0.5 * (p.a0 + p.a1) * len;
      b += 0.5 * (p.b0 + p.b1) * len;
    }
    const mMin = b > 0 ? (1 - a) / b : -Infinity;
    if (Number.isNaN(mMin) || mMin <= 0)
      throw new Error(
        `the focus regions leave no room for the context (M_min = ${mMin.toFixed(4)} <= 0)`,
      );
    this._mMin = mMin;
    this._pieces = [];
    let s = 0;
    for (const p of sym) {
      const piece = new Piece(p.t0, p.t1, p.a0 + p.b0 * mMin, p.a1 + p.b1 * mMin, s);
      s = piece.s1;
      this._pieces.push(piece);
    }
  }

  /** The focus regions (copies), sorted by centre. */
  get regions() {
    return this._regions.map((r) => ({ ...r }));
  }

  /** The solved context magnification M_min (1 without focus regions). */
  get mMin() {
    return this._mMin;
  }

  get isLinear() {
    return this._regions.length === 0;
  }

  _pieceAtT(t) {
    const i = partitionPoint(this._pieces, (p) => p.t1 < t);
    return this._pieces[Math.min(i, this._pieces.length - 1)];
  }

  /** The magnification M(t) at normalised data position t (Fig. 6b). */
  magnification(t) {
    const tc = clamp(t, 0, 1);
    const p = this._pieceAtT(tc);
    const f = (clamp(tc, p.t0, p.t1) - p.t0) / (p.t1 - p.t0);
    return p.m0 + (p.m1 - p.m0) * f;
  }

  /** Window position x in [0, 1] of normalised data position t (clamped to [0, 1]). */
  forward(t) {
    if (Number.isNaN(t)) return NaN;
    t = clamp(t, 0, 1);
    if (t >= 1) return 1;
    return clamp(this._pieceAtT(t).forward(t), 0, 1);
  }

  /** Normalised data position t of window position x (clamped); inverse of forward. */
  inverse(x) {
    if (Number.isNaN(x)) return NaN;
    x = clamp(x, 0, 1);
    if (x >= 1) return 1;
    const i = partitionPoint(this._pieces, (p) => p.s1 < x);
    return clamp(this._pieces[Math.min(i, this._pieces.length - 1)].inverse(x), 0, 1);
  }

  /** Eq. 2's left-hand side for this map: 1 up to rounding. */
  totalWidth() {
    return this._pieces.reduce((s, p) => s + 0.5 * (p.m0 + p.m1) * (p.t1 - p.t0), 0);
  }
}

/**
 * The vertical axis of the editor: 'linear' (y = v) or 'log' with a floor in (0, 1)
 * (y = 1 - log10(v) / log10(floor); values below the floor sit at the bottom).
 */
export class ValueAxis {
  constructor(kind = 'linear', floor = 1e-4) {
    if (kind !== 'linear' && kind !== 'log') throw new Error(`unknown value axis ${kind}`);
    if (kind === 'log' && !(floor > 0 && floor < 1))
      throw new Error(`the floor of a logarithmic axis must be in (0, 1), got ${floor}`);
    this.kind = kind;
    this.floor = floor;
  }
  /** Axis position y in [0, 1] of value v (clamped). */
  forward(v) {
    if (this.kind === 'linear') return clamp(v, 0, 1);
    const c = clamp(v, this.floor, 1);
    return clamp(1 - Math.log10(c) / Math.log10(this.floor), 0, 1);
  }
  /** Value at axis position y (clamped); inverse of forward on [floor, 1]. */
  inverse(y) {
    y = clamp(y, 0, 1);
    return this.kind === 'linear' ? y : Math.pow(this.floor, 1 - y);
  }
}

const coord = (v, axis) => (axis === 'log' ? Math.log10(v) : v);

/** Normalised position in [0, 1] of a data value on a 'linear' or 'log' data axis. */
export function normalize(value, domain, axis = 'linear') {
  const [lo, hi] = domain;
  const a = coord(lo, axis);
  const b = coord(hi, axis);
  return clamp((coord(clamp(value, lo, hi), axis) - a) / (b - a), 0, 1);
}

/** Inverse of `normalize`: the data value at normalised position t. */
export function valueAtNormalized(t, domain, axis = 'linear') {
  const [lo, hi] = domain;
  const a = coord(lo, axis);
  const b = coord(hi, axis);
  const c = a + (b - a) * clamp(t, 0, 1);
  return clamp(axis === 'log' ? Math.pow(10, c) : c, lo, hi);
}
