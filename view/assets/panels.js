// The control panels on the right: render settings and display, Doppler, relativity and
// HDR image (tone mapping). Each panel sends partial updates and shows the server's replies.

import { Throttle } from './net.js';

const el = (tag, props = {}, ...children) => {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
};
const row = (label, ...children) =>
  el('div', { className: 'row' }, el('label', { textContent: label }), ...children);
const select = (options, value) => {
  const s = el('select');
  for (const o of options) s.append(el('option', { value: o, textContent: o }));
  if (value !== undefined) s.value = value;
  return s;
};
const number = (step = 'any', props = {}) => el('input', { type: 'number', step, ...props });
const check = (text) => {
  const box = el('input', { type: 'checkbox' });
  return { box, label: el('label', { className: 'check' }, box, text) };
};
/** Sets an input's value unless the user is editing it. */
const put = (input, value) => {
  if (document.activeElement === input) return;
  if (input.type === 'checkbox') input.checked = Boolean(value);
  else input.value = String(value);
};
const finite = (s) => s.trim() !== '' && Number.isFinite(Number(s));
const short = (v) => (Math.abs(v) >= 1e3 || (v !== 0 && Math.abs(v) < 1e-2) ? v.toExponential(2) : String(Number(v.toPrecision(4))));

/** A log10 slider with a number box beside it; `zero` allows typing 0. */
function logSlider(min, max, onValue, { zero = false } = {}) {
  const s = el('input', { type: 'range', min, max, step: 0.01 });
  const n = number('any', { className: 'narrow', min: zero ? 0 : undefined });
  const set = (v) => {
    put(n, short(v));
    put(s, v > 0 ? Math.log10(v) : min);
  };
  s.addEventListener('input', () => {
    const v = Math.pow(10, Number(s.value));
    put(n, short(v));
    onValue(v, false);
  });
  s.addEventListener('change', () => onValue(Math.pow(10, Number(s.value)), true));
  n.addEventListener('change', () => {
    const v = Number(n.value);
    if (finite(n.value) && (v > 0 || (zero && v === 0))) {
      put(s, v > 0 ? Math.log10(v) : min);
      onValue(v, true);
    }
  });
  return { nodes: [s, n], set };
}

/** An exposure slider in stops; onValue(stops, final). */
function exposureSlider(onValue) {
  const s = el('input', { type: 'range', min: -10, max: 10, step: 0.1 });
  const v = el('span', { className: 'val' });
  const show = (e) => (v.textContent = `${Number(e).toFixed(1)} EV`);
  s.addEventListener('input', () => {
    show(s.value);
    onValue(Number(s.value), false);
  });
  s.addEventListener('change', () => onValue(Number(s.value), true));
  return {
    nodes: [s, v],
    set(e) {
      put(s, e);
      show(e);
    },
  };
}

const METHODS = ['woodcock', 'mdwt-ndda', 'mdwt-1dda', 'mdwt-summed', 'marcher'];
const BLENDS = ['density', 'max', 'mix', 'weighted', 'composite'];
const PRECISIONS = ['f32', 'f16', 'u8'];
const DISPLAY_OPS = ['exposure', 'linear', 'drago', 'reinhard', 'reinhard-local', 'durand', 'fattal'];

/** Render controls and the display (exposure, tone-map operator). */
export class RenderPanel {
  constructor(root, send, info) {
    const th = new Throttle(send, { merge: true });
    const set = (fields, final) => {
      th.push({ type: 'settings', ...fields });
      if (final) th.flush();
    };
    const s = info.settings || {};
    this.w = {};
    const w = this.w;
    w.method = select(METHODS, s.method);
    w.method.addEventListener('change', () => set({ method: w.method.value }, true));
    w.blend = select(BLENDS, s.blend);
    w.blend.addEventListener('change', () => set({ blend: w.blend.value }, true));
    w.spp = number(1, { min: 1, className: 'narrow' });
    w.spp.addEventListener('change', () => finite(w.spp.value) && set({ spp: Math.round(Number(w.spp.value)) }, true));
    w.noise = number('any', { min: 0, className: 'narrow', placeholder: 'none' });
    w.noise.addEventListener('change', () =>
      set({ noise_target: finite(w.noise.value) ? Number(w.noise.value) : null }, true),
    );
    w.density = number('any', { min: 0, className: 'narrow' });
    w.density.addEventListener(
      'change',
      () => finite(w.density.value) && set({ density_scale: Number(w.density.value) }, true),
    );
    const light = check('light');
    w.light = light.box;
    w.lx = number('any', { className: 'tiny' });
    w.ly = number('any', { className: 'tiny' });
    w.lz = number('any', { className: 'tiny' });
    const sendLight = () => {
      const v = [w.lx, w.ly, w.lz].map((i) => Number(i.value));
      if (!w.light.checked) set({ light_dir: null }, true);
      else if (v.every(Number.isFinite) && v.some((c) => c !== 0)) set({ light_dir: v }, true);
    };
    for (const i of [w.light, w.lx, w.ly, w.lz]) i.addEventListener('change', sendLight);
    const shading = check('shading');
    w.shading = shading.box;
    w.shading.addEventListener('change', () => set({ shading: w.shading.checked }, true));
    w.precision = select(PRECISIONS, s.precision);
    w.precision.addEventListener('change', () => set({ precision: w.precision.value }, true));
    w.device = select(['auto', 'cpu', 'gpu'], s.device);
    const gpu = info.devices?.gpu;
    w.device.querySelector('option[value=gpu]').disabled = !gpu;
    w.device.addEventListener('change', () => set({ device: w.device.value }, true));
    const devText = el('div', {
      className: 'note',
      textContent: `cpu: ${info.devices?.cpu ?? '?'} · gpu: ${gpu ?? 'none'}`,
    });
    // The observer flying into the picture (aberration and colour shift; scene `observer_velocity`).
    w.beta = el('input', { type: 'range', min: 0, max: 0.95, step: 0.01, value: 0, id: 'render-beta' });
    w.betaVal = el('span', { className: 'val', textContent: '0.00' });
    const sendBeta = (final) => {
      w.betaVal.textContent = Number(w.beta.value).toFixed(2);
      set({ beta: Number(w.beta.value) }, final);
    };
    w.beta.addEventListener('input', () => sendBeta(false));
    w.beta.addEventListener('change', () => sendBeta(true));
    w.exposure = exposureSlider((e, final) => set({ exposure: e }, final));
    w.tonemap = select(DISPLAY_OPS, s.tonemap);
    w.tonemap.addEventListener('change', () => set({ tonemap: w.tonemap.value }, true));
    this.progress = el('div', { className: 'note' });
    // Only the rows whose fields this mode's settings have (Doppler and relativity scenes
    // have few: their own panels carry the rest).
    const has = (k) => k in s;
    const rows = [
      [has('method'), row('method', w.method)],
      [has('blend'), row('blend', w.blend)],
      [has('spp'), row('spp target', w.spp, el('label', { textContent: 'noise' }), w.noise)],
      [has('density_scale'), row('density scale', w.density)],
      [has('light_dir'), row('', light.label, w.lx, w.ly, w.lz, shading.label)],
      [has('precision'), row('precision', w.precision, el('span', { className: 'note', textContent: '(marcher)' }))],
      [has('beta'), row('observer \u03b2', w.beta, w.betaVal)],
      [has('device'), row('device', w.device)],
      [has('device'), devText],
      [has('exposure') || has('tonemap'), el('h3', { textContent: 'Display' })],
      [has('exposure'), row('exposure', ...w.exposure.nodes)],
      [has('tonemap'), row('tone map', w.tonemap)],
    ];
    root.replaceChildren(
      el('h3', { textContent: 'Render' }),
      ...rows.filter(([show]) => show).map(([, node]) => node),
      this.progress,
    );
    this.update(s);
  }

  /** Shows a `settings` reply. */
  update(s) {
    const w = this.w;
    if (s.method !== undefined) put(w.method, s.method);
    if (s.blend !== undefined) put(w.blend, s.blend);
    if (s.spp !== undefined) put(w.spp, s.spp);
    if (s.noise_target !== undefined) put(w.noise, s.noise_target ?? '');
    if (s.density_scale !== undefined) put(w.density, s.density_scale);
    if (s.light_dir !== undefined) {
      put(w.light, s.light_dir !== null);
      if (s.light_dir) [w.lx, w.ly, w.lz].forEach((i, k) => put(i, s.light_dir[k]));
    }
    if (s.shading !== undefined) put(w.shading, s.shading);
    if (s.precision !== undefined) put(w.precision, s.precision);
    if (s.device !== undefined) put(w.device, s.device);
    if (s.exposure !== undefined) w.exposure.set(s.exposure);
    if (s.tonemap !== undefined) put(w.tonemap, s.tonemap);
    if (s.beta !== undefined) {
      put(w.beta, s.beta);
      w.betaVal.textContent = Number(s.beta).toFixed(2);
    }
  }

  /** Shows a `status` message's progress. */
  status(st) {
    const noise = st.noise === null || st.noise === undefined ? '–' : st.noise.toExponential(2);
    this.progress.textContent = `current: ${st.spp} / ${st.target_spp} spp, noise ${noise}`;
  }
}

const FACTORS = ['velocity', 'temperature', 'emission', 'absorption', 'blackbody'];
const FACTOR_LABELS = {
  velocity: 'velocity',
  temperature: 'temperature',
  emission: 'emission',
  absorption: 'absorption',
  blackbody: 'black body',
};

/** Doppler mode: the Table 1 factors, integrator, picking, trace and velocity panel. */
export class DopplerPanel {
  constructor(root, send, state, { onTrace, onPanels }) {
    const th = new Throttle(send, { merge: true });
    this.factors = { ...(state?.factors || {}) };
    const set = (fields, final) => {
      th.push({ type: 'doppler', ...fields });
      if (final) th.flush();
    };
    const enabled = check('Doppler shift on');
    this.enabled = enabled.box;
    this.enabled.addEventListener('change', () => set({ enabled: this.enabled.checked }, true));
    this.sliders = {};
    const rows = FACTORS.map((f) => {
      const s = logSlider(-3, 3, (v, final) => {
        this.factors[f] = v;
        set({ factors: { ...this.factors } }, final);
      }, { zero: f === 'absorption' });
      this.sliders[f] = s;
      return row(FACTOR_LABELS[f], ...s.nodes);
    });
    this.integrator = select(['pwl', 'banded']);
    this.integrator.addEventListener('change', () => set({ integrator: this.integrator.value }, true));
    this.tol = number('any', { min: 0, className: 'narrow' });
    this.tol.addEventListener(
      'change',
      () => finite(this.tol.value) && set({ merge_tolerance: Number(this.tol.value) }, true),
    );
    this.traceBtn = el('button', { textContent: 'trace picked pixel', disabled: true });
    this.traceBtn.addEventListener('click', onTrace);
    const panelsBtn = el('button', { textContent: 'velocity panel' });
    panelsBtn.addEventListener('click', onPanels);
    this.lines = el('div', { className: 'note' });
    // The observer flying into the picture (relativistic Doppler shift; `doppler --beta`).
    this.beta = el('input', { type: 'range', min: 0, max: 0.95, step: 0.01, value: 0, id: 'observer-beta' });
    this.betaVal = el('span', { className: 'val', textContent: '0.00' });
    const sendBeta = (final) => {
      this.betaVal.textContent = Number(this.beta.value).toFixed(2);
      set({ beta: Number(this.beta.value) }, final);
    };
    this.beta.addEventListener('input', () => sendBeta(false));
    this.beta.addEventListener('change', () => sendBeta(true));
    this.exposure = exposureSlider((e, final) => set({ exposure: e }, final));
    root.replaceChildren(
      el('h3', { textContent: 'Doppler (Table 1 factors)' }),
      row('', enabled.label),
      ...rows,
      row('integrator', this.integrator, el('label', { textContent: 'merge tol.' }), this.tol),
      row('observer \u03b2', this.beta, this.betaVal),
      ...(state && 'exposure' in state ? [row('exposure', ...this.exposure.nodes)] : []),
      el('div', { className: 'note', textContent: 'click the image to plot a pixel\u2019s spectrum' }),
      row('', this.traceBtn, panelsBtn),
      this.lines,
    );
    if (state) this.update(state);
  }

  /** Shows a `doppler` reply. */
  update(d) {
    if (d.enabled !== undefined) put(this.enabled, d.enabled);
    if (d.factors) {
      this.factors = { ...d.factors };
      for (const f of FACTORS) if (d.factors[f] !== undefined) this.sliders[f].set(d.factors[f]);
    }
    if (d.integrator !== undefined) put(this.integrator, d.integrator);
    if (d.exposure !== undefined) this.exposure.set(d.exposure);
    if (d.merge_tolerance !== undefined) put(this.tol, d.merge_tolerance);
    if (d.beta !== undefined) {
      put(this.beta, d.beta);
      this.betaVal.textContent = Number(d.beta).toFixed(2);
    }
    if (d.lines)
      this.lines.textContent = `lines: ${d.lines.map((l) => `${l.name} ${l.rest_nm} nm`).join(', ')}`;
  }
}

/**
 * Relativity mode: beta, the direction of motion on a sphere widget (a disc seen along -z:
 * x right, y up, z towards the viewer; the back hemisphere drawn hollow), the effect toggles
 * and the look direction (also set by dragging the main view).
 */
export class RelativityPanel {
  constructor(root, send, state) {
    this.th = new Throttle(send, { merge: true });
    this.state = {
      beta: 0,
      direction: [0, 0, -1],
      effects: { aberration: true, doppler: true, searchlight: true },
      yaw: 0,
      pitch: 0,
      fov: 60,
      ...(state || {}),
    };
    this.beta = el('input', { type: 'range', min: 0, max: 0.99, step: 0.001 });
    this.betaVal = el('span', { className: 'val' });
    this.beta.addEventListener('input', () => {
      this.state.beta = Number(this.beta.value);
      this.betaVal.textContent = this.state.beta.toFixed(3);
      this._set({ beta: this.state.beta }, false);
    });
    this.beta.addEventListener('change', () => this._set({ beta: this.state.beta }, true));
    this.toggles = {};
    const labels = ['aberration', 'doppler', 'searchlight'].map((k) => {
      const c = check(k);
      this.toggles[k] = c.box;
      c.box.addEventListener('change', () => {
        this.state.effects = { ...this.state.effects, [k]: c.box.checked };
        this._set({ effects: this.state.effects }, true);
      });
      return c.label;
    });
    this.sphere = el('canvas', { id: 'rel-sphere', width: 130, height: 130 });
    this.dirText = el('div', { className: 'note' });
    this._bindSphere();
    this.fov = number('any', { min: 1, max: 179, className: 'narrow' });
    this.fov.addEventListener('change', () => {
      if (!finite(this.fov.value)) return;
      this.state.fov = Number(this.fov.value);
      this._set({ fov: this.state.fov }, true);
    });
    this.lookText = el('span', { className: 'val' });
    this.exposure = exposureSlider((e, final) => this._set({ exposure: e }, final));
    root.replaceChildren(
      el('h3', { textContent: 'Relativity' }),
      row('beta', this.beta, this.betaVal),
      ...(state && 'exposure' in state ? [row('exposure', ...this.exposure.nodes)] : []),
      row('', ...labels),
      row('motion', this.sphere, this.dirText),
      row('look', this.lookText, el('label', { textContent: 'fov' }), this.fov),
      el('div', { className: 'note', textContent: 'drag the image to look around; drag the sphere to turn the direction of motion' }),
    );
    this.update(this.state);
  }

  _set(fields, final) {
    this.th.push({ type: 'relativity', ...fields });
    if (final) this.th.flush();
  }

  /** Look drag on the main view (pixels); `final` on release. */
  look(dx, dy, final) {
    const s = this.state;
    s.yaw = ((s.yaw - dx * 0.25 + 540) % 360) - 180;
    s.pitch = Math.max(-89.9, Math.min(89.9, s.pitch + dy * 0.25));
    this.lookText.textContent = `yaw ${s.yaw.toFixed(1)}°, pitch ${s.pitch.toFixed(1)}°`;
    this._set({ yaw: s.yaw, pitch: s.pitch }, final);
  }

  _bindSphere() {
    const cv = this.sphere;
    let last = null;
    cv.addEventListener('pointerdown', (ev) => {
      cv.setPointerCapture(ev.pointerId);
      last = [ev.clientX, ev.clientY];
    });
    cv.addEventListener('pointermove', (ev) => {
      if (!last) return;
      const a = (ev.clientX - last[0]) * 0.02; // about the screen's vertical axis
      const b = (ev.clientY - last[1]) * 0.02; // about the screen's horizontal axis
      last = [ev.clientX, ev.clientY];
      let [x, y, z] = this.state.direction;
      [x, z] = [x * Math.cos(a) + z * Math.sin(a), -x * Math.sin(a) + z * Math.cos(a)];
      [y, z] = [y * Math.cos(b) - z * Math.sin(b), y * Math.sin(b) + z * Math.cos(b)];
      const n = Math.hypot(x, y, z) || 1;
      this.state.direction = [x / n, y / n, z / n];
      this._drawSphere();
      this._set({ direction: this.state.direction }, false);
    });
    const end = () => {
      if (!last) return;
      last = null;
      this._set({ direction: this.state.direction }, true);
    };
    cv.addEventListener('pointerup', end);
    cv.addEventListener('pointercancel', end);
  }

  _drawSphere() {
    const c = this.sphere.getContext('2d');
    const w = this.sphere.width;
    const r = w / 2 - 8;
    const cx = w / 2;
    c.clearRect(0, 0, w, w);
    const g = c.createRadialGradient(cx - r / 3, cx - r / 3, r / 8, cx, cx, r);
    g.addColorStop(0, '#3a4652');
    g.addColorStop(1, '#1a2027');
    c.fillStyle = g;
    c.beginPath();
    c.arc(cx, cx, r, 0, 2 * Math.PI);
    c.fill();
    c.strokeStyle = '#566';
    c.stroke();
    c.beginPath();
    c.moveTo(cx - r, cx);
    c.lineTo(cx + r, cx);
    c.moveTo(cx, cx - r);
    c.lineTo(cx, cx + r);
    c.stroke();
    c.fillStyle = '#9aa3ad';
    c.font = '10px sans-serif';
    c.fillText('+x', cx + r - 12, cx - 3);
    c.fillText('+y', cx + 3, cx - r + 10);
    const [x, y, z] = this.state.direction;
    const px = cx + x * r;
    const py = cx - y * r;
    c.strokeStyle = '#fc6';
    c.lineWidth = 2;
    c.beginPath();
    c.moveTo(cx, cx);
    c.lineTo(px, py);
    c.stroke();
    c.lineWidth = 1;
    c.beginPath();
    c.arc(px, py, 5, 0, 2 * Math.PI);
    if (z >= 0) {
      c.fillStyle = '#fc6';
      c.fill();
    } else c.stroke();
    this.dirText.textContent = `(${x.toFixed(2)}, ${y.toFixed(2)}, ${z.toFixed(2)}) ${z >= 0 ? 'front' : 'back'}`;
  }

  /** Shows a `relativity` reply. */
  update(r) {
    Object.assign(this.state, r);
    put(this.beta, this.state.beta);
    this.betaVal.textContent = Number(this.state.beta).toFixed(3);
    for (const k of Object.keys(this.toggles)) put(this.toggles[k], this.state.effects?.[k]);
    put(this.fov, this.state.fov);
    if (this.state.exposure !== undefined) this.exposure.set(this.state.exposure);
    this.lookText.textContent = `yaw ${Number(this.state.yaw).toFixed(1)}°, pitch ${Number(this.state.pitch).toFixed(1)}°`;
    this._drawSphere();
  }
}

/**
 * HDR image mode: operator and its parameters, exposure, pseudocolour, Drago's region of
 * interest. The server keeps the exposure in the operator's `exposure_stops` parameter and
 * the ROI in Drago's `roi` parameter (a circle: centre and radius in pixels); the page sends
 * them as the message's `exposure` and `roi` fields (the ROI only to Drago).
 */
export class HdrPanel {
  constructor(root, send, state, { onRoiChange }) {
    this.onRoiChange = onRoiChange;
    this.th = new Throttle(send, { merge: true });
    this.defaults = state.defaults || {};
    this.state = {
      operator: state.operator,
      params: { ...(state.params || {}) },
      pseudocolour: Boolean(state.pseudocolour),
    };
    this.op = select(Object.keys(this.defaults), state.operator);
    this.op.addEventListener('change', () => {
      this.state.operator = this.op.value;
      this.state.params = { ...this.defaults[this.op.value] };
      this._buildParams();
      this._send({ operator: this.op.value }, true);
      this._show();
    });
    this.paramsBox = el('div');
    this.exposure = exposureSlider((e, final) => this._send({ exposure: e }, final));
    this.exposureRow = row('exposure', ...this.exposure.nodes);
    const pc = check('pseudocolour');
    this.pseudo = pc.box;
    this.pseudo.addEventListener('change', () => {
      this.state.pseudocolour = this.pseudo.checked;
      this._send({ pseudocolour: this.pseudo.checked }, true);
      this._show();
    });
    this.colourbar = el('canvas', { id: 'colourbar', width: 256, height: 16 });
    this.roiText = el('span', { className: 'val' });
    const clear = el('button', { textContent: 'clear ROI' });
    clear.addEventListener('click', () => this.roiActive() && this._send({ roi: null }, true));
    this.roiRows = [
      row('ROI', this.roiText, clear),
      el('div', { className: 'note', textContent: 'drag a rectangle on the image: the region of interest is its inscribed circle' }),
    ];
    root.replaceChildren(
      el('h3', { textContent: 'HDR image: tone mapping' }),
      row('operator', this.op),
      this.paramsBox,
      this.exposureRow,
      row('', pc.label),
      this.colourbar,
      ...this.roiRows,
    );
    this._buildParams();
    this._show();
  }

  /** Whether a drag on the image sets the ROI (Drago only). */
  roiActive() {
    return this.state.operator === 'drago';
  }

  /** A rectangle [x0, y0, x1, y1] dragged on the image. */
  setRoi(roi) {
    this._send({ roi }, true);
  }

  _send(fields, final) {
    this.th.push({ type: 'tonemap', operator: this.state.operator, ...fields });
    if (final) this.th.flush();
  }

  /**
   * One input per numeric or boolean parameter of the operator (exposure and ROI have
   * their own controls); null-able ones get an 'auto' checkbox.
   */
  _buildParams() {
    const defs = this.defaults[this.state.operator] || {};
    this.paramInputs = {};
    const rows = [];
    for (const name of Object.keys(defs)) {
      if (name === 'exposure_stops' || name === 'roi') continue;
      const d = defs[name];
      if (typeof d === 'boolean') {
        const c = check('');
        c.box.addEventListener('change', () => this._send({ params: { [name]: c.box.checked } }, true));
        this.paramInputs[name] = { input: c.box };
        rows.push(row(name, c.label));
        continue;
      }
      if (d !== null && typeof d !== 'number') continue;
      const input = number('any', { className: 'narrow' });
      const nullable = d === null;
      const auto = check('auto');
      const apply = () => {
        if (nullable && auto.box.checked) this._send({ params: { [name]: null } }, true);
        else if (finite(input.value)) this._send({ params: { [name]: Number(input.value) } }, true);
        input.disabled = nullable && auto.box.checked;
      };
      input.addEventListener('change', apply);
      auto.box.addEventListener('change', () => {
        if (!auto.box.checked && !finite(input.value)) input.value = '1';
        apply();
      });
      this.paramInputs[name] = { input, auto: nullable ? auto.box : null };
      rows.push(nullable ? row(name, input, auto.label) : row(name, input));
    }
    this.paramsBox.replaceChildren(...rows);
  }

  /** Shows the state in the widgets. */
  _show() {
    const p = this.state.params || {};
    put(this.op, this.state.operator);
    for (const [name, w] of Object.entries(this.paramInputs)) {
      const v = p[name];
      if (w.input.type === 'checkbox') put(w.input, v);
      else {
        if (w.auto) w.auto.checked = v === null || v === undefined;
        w.input.disabled = Boolean(w.auto && w.auto.checked);
        if (typeof v === 'number') put(w.input, short(v));
      }
    }
    const hasExposure = 'exposure_stops' in p;
    this.exposureRow.hidden = !hasExposure;
    if (hasExposure) this.exposure.set(p.exposure_stops);
    put(this.pseudo, this.state.pseudocolour);
    // The server may put the bar into the frame itself; show ours once one arrived.
    this.colourbar.hidden = !this.state.pseudocolour || !this.colourbar.dataset.drawn;
    for (const r of this.roiRows) r.hidden = !this.roiActive();
    const roi = this.roiActive() ? p.roi : null;
    this.roiText.textContent = roi
      ? `centre (${roi.x_px.toFixed(0)}, ${roi.y_px.toFixed(0)}), radius ${roi.radius_px.toFixed(0)} px`
      : 'none (whole image)';
    this.onRoiChange(roi ?? null);
  }

  /** Shows a `tonemap` reply. */
  update(t) {
    const rebuild = t.operator !== undefined && t.operator !== this.state.operator;
    if (t.defaults) this.defaults = t.defaults;
    if (t.operator !== undefined) this.state.operator = t.operator;
    if (t.params) this.state.params = { ...t.params };
    if (t.pseudocolour !== undefined) this.state.pseudocolour = t.pseudocolour;
    if (rebuild) this._buildParams();
    this._show();
  }
}
