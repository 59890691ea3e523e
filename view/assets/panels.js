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
    w.exposure = el('input', { type: 'range', min: -10, max: 10, step: 0.1 });
    w.exposureVal = el('span', { className: 'val' });
    w.exposure.addEventListener('input', () => {
      w.exposureVal.textContent = `${Number(w.exposure.value).toFixed(1)} EV`;
      set({ exposure: Number(w.exposure.value) }, false);
    });
    w.tonemap = select(DISPLAY_OPS, s.tonemap);
    w.tonemap.addEventListener('change', () => set({ tonemap: w.tonemap.value }, true));
    this.progress = el('div', { className: 'note' });
    root.replaceChildren(
      el('h3', { textContent: 'Render' }),
      row('method', w.method),
      row('blend', w.blend),
      row('spp target', w.spp, el('label', { textContent: 'noise' }), w.noise),
      row('density scale', w.density),
      row('', light.label, w.lx, w.ly, w.lz, shading.label),
      row('precision', w.precision, el('span', { className: 'note', textContent: '(marcher)' })),
      row('device', w.device),
      devText,
      el('h3', { textContent: 'Display' }),
      row('exposure', w.exposure, w.exposureVal),
      row('tone map', w.tonemap),
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
    if (s.exposure !== undefined) {
      put(w.exposure, s.exposure);
      w.exposureVal.textContent = `${Number(s.exposure).toFixed(1)} EV`;
    }
    if (s.tonemap !== undefined) put(w.tonemap, s.tonemap);
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
    root.replaceChildren(
      el('h3', { textContent: 'Doppler (Table 1 factors)' }),
      row('', enabled.label),
      ...rows,
      row('integrator', this.integrator, el('label', { textContent: 'merge tol.' }), this.tol),
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
    if (d.merge_tolerance !== undefined) put(this.tol, d.merge_tolerance);
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
    root.replaceChildren(
      el('h3', { textContent: 'Relativity' }),
      row('beta', this.beta, this.betaVal),
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
    this.lookText.textContent = `yaw ${Number(this.state.yaw).toFixed(1)}°, pitch ${Number(this.state.pitch).toFixed(1)}°`;
    this._drawSphere();
  }
}

/** HDR image mode: operator and its parameters, exposure, pseudocolour, Drago's ROI. */
export class HdrPanel {
  constructor(root, send, state) {
    this.send = send;
    this.th = new Throttle(send);
    this.defaults = state.defaults || {};
    this.state = {
      operator: state.operator,
      params: { ...(state.params || {}) },
      exposure: state.exposure ?? 0,
      pseudocolour: Boolean(state.pseudocolour),
      roi: state.roi ?? null,
    };
    this.op = select(Object.keys(this.defaults), state.operator);
    this.op.addEventListener('change', () => {
      this.state.operator = this.op.value;
      this.state.params = { ...this.defaults[this.op.value] };
      this._buildParams();
      this._send(true);
    });
    this.paramsBox = el('div');
    this.exposure = el('input', { type: 'range', min: -10, max: 10, step: 0.1 });
    this.exposureVal = el('span', { className: 'val' });
    this.exposure.addEventListener('input', () => {
      this.state.exposure = Number(this.exposure.value);
      this.exposureVal.textContent = `${this.state.exposure.toFixed(1)} EV`;
      this._send(false);
    });
    this.exposure.addEventListener('change', () => this._send(true));
    const pc = check('pseudocolour');
    this.pseudo = pc.box;
    this.pseudo.addEventListener('change', () => {
      this.state.pseudocolour = this.pseudo.checked;
      this._send(true);
    });
    this.colourbar = el('canvas', { id: 'colourbar', width: 256, height: 16 });
    this.roiText = el('span', { className: 'val' });
    const clear = el('button', { textContent: 'clear ROI' });
    clear.addEventListener('click', () => {
      this.state.roi = null;
      this.onRoiChange?.(null);
      this._send(true);
    });
    root.replaceChildren(
      el('h3', { textContent: 'HDR image: tone mapping' }),
      row('operator', this.op),
      this.paramsBox,
      row('exposure', this.exposure, this.exposureVal),
      row('', pc.label),
      this.colourbar,
      row('ROI', this.roiText, clear),
      el('div', { className: 'note', textContent: 'Drago: drag a rectangle on the image to set the region of interest' }),
    );
    this._buildParams();
    this.update(this.state);
  }

  /** Whether a drag on the image sets the ROI (Drago only). */
  roiActive() {
    return this.state.operator === 'drago';
  }

  setRoi(roi) {
    this.state.roi = roi;
    this.roiText.textContent = `[${roi.join(', ')}]`;
    this._send(true);
  }

  _send(final) {
    this.th.push({ type: 'tonemap', ...structuredClone(this.state) });
    if (final) this.th.flush();
  }

  /** One input per parameter of the operator; null-able ones get an 'auto' checkbox. */
  _buildParams() {
    const defs = this.defaults[this.state.operator] || {};
    this.paramInputs = {};
    const rows = Object.keys(defs).map((name) => {
      const d = defs[name];
      if (typeof d === 'boolean') {
        const c = check('');
        c.box.checked = Boolean(this.state.params[name] ?? d);
        c.box.addEventListener('change', () => {
          this.state.params[name] = c.box.checked;
          this._send(true);
        });
        this.paramInputs[name] = { input: c.box };
        return row(name, c.label);
      }
      const input = number('any', { className: 'narrow' });
      const auto = check('auto');
      const nullable = d === null;
      const v = this.state.params[name];
      input.value = v === null || v === undefined ? (d ?? '') : String(v);
      auto.box.checked = nullable && (v === null || v === undefined);
      input.disabled = auto.box.checked;
      const apply = () => {
        if (auto.box.checked) this.state.params[name] = null;
        else if (finite(input.value)) this.state.params[name] = Number(input.value);
        else return;
        input.disabled = auto.box.checked;
        this._send(true);
      };
      input.addEventListener('change', apply);
      auto.box.addEventListener('change', () => {
        if (!auto.box.checked && !finite(input.value)) input.value = '1';
        apply();
      });
      this.paramInputs[name] = { input, auto: nullable ? auto.box : null };
      return nullable ? row(name, input, auto.label) : row(name, input);
    });
    this.paramsBox.replaceChildren(...rows);
  }

  /** Shows a `tonemap` reply. */
  update(t) {
    const rebuild = t.operator !== undefined && t.operator !== this.op.value;
    Object.assign(this.state, structuredClone(t));
    delete this.state.defaults;
    delete this.state.type;
    put(this.op, this.state.operator);
    if (rebuild) this._buildParams();
    for (const [name, w] of Object.entries(this.paramInputs)) {
      const v = this.state.params?.[name];
      if (w.input.type === 'checkbox') put(w.input, v);
      else if (v === null) {
        if (w.auto) w.auto.checked = true;
        w.input.disabled = true;
      } else if (v !== undefined) put(w.input, v);
    }
    put(this.exposure, this.state.exposure);
    this.exposureVal.textContent = `${Number(this.state.exposure).toFixed(1)} EV`;
    put(this.pseudo, this.state.pseudocolour);
    this.colourbar.style.display = this.state.pseudocolour ? '' : 'none';
    const r = this.state.roi;
    this.roiText.textContent = r ? `[${r.join(', ')}]` : 'none (whole image)';
    this.onRoiChange?.(r);
  }
}
