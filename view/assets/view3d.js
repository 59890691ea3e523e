// The main view: draws the server's frames, moves the camera with the mouse and keys
// (turntable orbit about the current up, pan, dolly zoom), and draws an overlay with the
// orientation triad, the picked pixel and Drago's region of interest.

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [
  a[1] * b[2] - a[2] * b[1],
  a[2] * b[0] - a[0] * b[2],
  a[0] * b[1] - a[1] * b[0],
];
const norm = (a) => Math.hypot(a[0], a[1], a[2]);
const unit = (a) => scale(a, 1 / (norm(a) || 1));

/** Rotates v about the unit axis k by angle a (Rodrigues). */
function rotate(v, k, a) {
  const c = Math.cos(a);
  const s = Math.sin(a);
  return add(add(scale(v, c), scale(cross(k, v), s)), scale(k, dot(k, v) * (1 - c)));
}

/** Camera basis: forward, image x (= forward x up) and image "up" (image y points down). */
export function cameraBasis(cam) {
  const f = unit(sub(cam.target, cam.eye));
  const r = unit(cross(f, cam.up));
  const u = cross(r, f);
  return { f, r, u };
}

const ORBIT_RAD_PER_PX = 0.01;
const KEY_ORBIT_RAD = (5 * Math.PI) / 180;
const CLICK_SLOP_PX = 4;
const ECHO_GRACE_MS = 300;

export class View3D {
  /**
   * canvas: #view; overlay: the canvas on top of it. Callbacks: sendCamera(cam, final),
   * onClick(x, y) (full-resolution pixel), onLook(dxPx, dyPx, final) (relativity),
   * onRoi([x0, y0, x1, y1]) and roiActive() (HDR), onKeyView(name).
   */
  constructor(canvas, overlay, callbacks) {
    this.canvas = canvas;
    this.overlay = overlay;
    this.cb = callbacks;
    this.ctx = canvas.getContext('2d', { willReadFrequently: true });
    this.mode = 'tracking';
    this.camera = null;
    this.drag = null;
    this.pickMark = null; // [x, y] full-resolution pixel
    this.roi = null; // [x0, y0, x1, y1] while a rectangle is dragged
    this.roiCircle = null; // Drago's region of interest {x_px, y_px, radius_px}
    this.lastLocalMove = -Infinity;
    this._bindMouse();
    new ResizeObserver(() => this.drawOverlay()).observe(canvas);
  }

  setInfo(info) {
    this.mode = info.mode;
    if (this.canvas.width !== info.width || this.canvas.height !== info.height) {
      this.canvas.width = info.width;
      this.canvas.height = info.height;
    }
    this.canvas.style.aspectRatio = `${info.width} / ${info.height}`;
    this.camera = info.camera ? { ...info.camera } : null;
    this.drawOverlay();
  }

  /**
   * A camera from the server. Ignored while the user moves the camera and shortly after
   * (the echoes of our own messages lag behind the local state).
   */
  setCamera(cam) {
    if (this.drag && this.drag.kind !== 'none') return;
    if (performance.now() - this.lastLocalMove < ECHO_GRACE_MS) return;
    this.camera = { ...this.camera, ...cam };
    this.drawOverlay();
  }

  /**
   * Draws a decoded frame, scaling a (smaller) preview up to the canvas. A full frame of
   * another size than the canvas (e.g. the HDR pseudocolour view with its colour bar beside
   * the image) resizes the canvas: canvas pixels stay image pixels.
   */
  drawFrame(bitmap, preview) {
    if (!preview && (bitmap.width !== this.canvas.width || bitmap.height !== this.canvas.height)) {
      this.canvas.width = bitmap.width;
      this.canvas.height = bitmap.height;
      this.canvas.style.aspectRatio = `${bitmap.width} / ${bitmap.height}`;
    }
    const c = this.ctx;
    c.imageSmoothingEnabled = true;
    c.imageSmoothingQuality = 'high';
    c.drawImage(bitmap, 0, 0, this.canvas.width, this.canvas.height);
  }

  /** Mean Rec. 709 luminance of the 8-bit canvas values, in [0, 1]. */
  meanLuminance() {
    const { data } = this.ctx.getImageData(0, 0, this.canvas.width, this.canvas.height);
    let sum = 0;
    for (let i = 0; i < data.length; i += 4)
      sum += 0.2126 * data[i] + 0.7152 * data[i + 1] + 0.0722 * data[i + 2];
    return sum / (255 * (data.length / 4));
  }

  /** Full-resolution pixel under a mouse event. */
  pixelAt(ev) {
    const rect = this.canvas.getBoundingClientRect();
    const x = Math.floor(((ev.clientX - rect.left) / rect.width) * this.canvas.width);
    const y = Math.floor(((ev.clientY - rect.top) / rect.height) * this.canvas.height);
    const { width, height } = this.canvas;
    return [Math.min(width - 1, Math.max(0, x)), Math.min(height - 1, Math.max(0, y))];
  }

  _bindMouse() {
    const el = this.overlay;
    el.addEventListener('contextmenu', (ev) => ev.preventDefault());
    el.addEventListener('pointerdown', (ev) => {
      el.setPointerCapture(ev.pointerId);
      const pan = ev.button === 2 || ev.shiftKey;
      let kind = 'none';
      if (this.mode === 'relativity') kind = 'look';
      else if (this.mode === 'hdr') kind = this.cb.roiActive() ? 'roi' : 'none';
      else if (this.camera) kind = pan ? 'pan' : 'orbit';
      this.drag = { kind, x0: ev.clientX, y0: ev.clientY, x: ev.clientX, y: ev.clientY };
      this.drag.moved = false;
      this.drag.p0 = this.pixelAt(ev);
    });
    el.addEventListener('pointermove', (ev) => {
      const d = this.drag;
      if (!d) return;
      const dx = ev.clientX - d.x;
      const dy = ev.clientY - d.y;
      if (Math.hypot(ev.clientX - d.x0, ev.clientY - d.y0) > CLICK_SLOP_PX) d.moved = true;
      if (!d.moved) return;
      d.x = ev.clientX;
      d.y = ev.clientY;
      if (d.kind === 'orbit') this.orbit(-dx * ORBIT_RAD_PER_PX, -dy * ORBIT_RAD_PER_PX, false);
      else if (d.kind === 'pan') this.pan(dx, dy, false);
      else if (d.kind === 'look') this.cb.onLook(dx, dy, false);
      else if (d.kind === 'roi') {
        const p = this.pixelAt(ev);
        this.roi = [
          Math.min(d.p0[0], p[0]),
          Math.min(d.p0[1], p[1]),
          Math.max(d.p0[0], p[0]) + 1,
          Math.max(d.p0[1], p[1]) + 1,
        ];
        this.drawOverlay();
      }
    });
    const end = (ev) => {
      const d = this.drag;
      if (!d) return;
      this.drag = null;
      if (!d.moved) {
        if (ev.type === 'pointerup' && ev.button === 0) this.cb.onClick(...this.pixelAt(ev));
        return;
      }
      if (d.kind === 'orbit' || d.kind === 'pan') this.cb.sendCamera(this.camera, true);
      else if (d.kind === 'look') this.cb.onLook(0, 0, true);
      else if (d.kind === 'roi' && this.roi) {
        this.cb.onRoi(this.roi);
        this.roi = null;
        this.drawOverlay();
      }
    };
    el.addEventListener('pointerup', end);
    el.addEventListener('pointercancel', end);
    el.addEventListener(
      'wheel',
      (ev) => {
        if (!this.camera || this.mode === 'relativity' || this.mode === 'hdr') return;
        ev.preventDefault();
        this.zoom(Math.exp(ev.deltaY * 0.0015), false);
      },
      { passive: false },
    );
  }

  /** A view preset was requested: its `camera` reply must not be taken for an echo. */
  presetRequested() {
    this.lastLocalMove = -Infinity;
  }

  /** Keyboard: arrows orbit, +/- zoom, x/y/z/i view presets. Returns true if handled. */
  key(ev) {
    if (!this.camera || this.mode === 'relativity' || this.mode === 'hdr') return false;
    const presets = { x: 'x', y: 'y', z: 'z', X: '-x', Y: '-y', Z: '-z', i: 'iso' };
    switch (ev.key) {
      case 'ArrowLeft':
        this.orbit(KEY_ORBIT_RAD, 0, true);
        return true;
      case 'ArrowRight':
        this.orbit(-KEY_ORBIT_RAD, 0, true);
        return true;
      case 'ArrowUp':
        this.orbit(0, KEY_ORBIT_RAD, true);
        return true;
      case 'ArrowDown':
        this.orbit(0, -KEY_ORBIT_RAD, true);
        return true;
      case '+':
      case '=':
        this.zoom(1 / 1.15, true);
        return true;
      case '-':
      case '_':
        this.zoom(1.15, true);
        return true;
      default:
        if (presets[ev.key]) {
          this.cb.onKeyView(presets[ev.key]);
          return true;
        }
        return false;
    }
  }

  /** Turntable orbit: yaw about the camera's up, pitch about image x, around the target. */
  orbit(yaw, pitch, final) {
    const cam = this.camera;
    const up = unit(cam.up);
    let off = sub(cam.eye, cam.target);
    off = rotate(off, up, yaw);
    const { r } = cameraBasis({ ...cam, eye: add(cam.target, off) });
    const pitched = rotate(off, r, pitch);
    // Keep clear of the poles, where the turntable degenerates.
    if (Math.abs(dot(unit(pitched), up)) < Math.cos((2 * Math.PI) / 180)) off = pitched;
    cam.eye = add(cam.target, off);
    this.lastLocalMove = performance.now();
    this.cb.sendCamera(cam, final);
    this.drawOverlay();
  }

  /** Pans eye and target so the scene follows the mouse (dx, dy in CSS pixels). */
  pan(dx, dy, final) {
    const cam = this.camera;
    const { r, u } = cameraBasis(cam);
    const dist = norm(sub(cam.eye, cam.target));
    const rect = this.canvas.getBoundingClientRect();
    let worldPerPx;
    if (cam.projection === 'orthographic' || !(cam.fov > 0)) {
      // The orthographic window spans about the volume's diagonal at zoom 1.
      const [b0, b1] = cam.bounds || [[-1, -1, -1], [1, 1, 1]];
      worldPerPx = norm(sub(b1, b0)) / (cam.zoom || 1) / rect.height;
    } else {
      const fov = (cam.fov * Math.PI) / 180;
      worldPerPx = (2 * dist * Math.tan(fov / 2)) / rect.height;
    }
    const move = add(scale(r, -dx * worldPerPx), scale(u, dy * worldPerPx));
    cam.eye = add(cam.eye, move);
    cam.target = add(cam.target, move);
    this.lastLocalMove = performance.now();
    this.cb.sendCamera(cam, final);
  }

  /** Dollies the eye towards (factor < 1) or away from the target; orthographic: scales. */
  zoom(factor, final) {
    const cam = this.camera;
    if (cam.projection === 'orthographic') {
      cam.zoom = (cam.zoom || 1) / factor;
      this.lastLocalMove = performance.now();
      this.cb.sendCamera(cam, final);
      return;
    }
    const off = scale(sub(cam.eye, cam.target), factor);
    if (norm(off) < 1e-6) return;
    cam.eye = add(cam.target, off);
    this.lastLocalMove = performance.now();
    this.cb.sendCamera(cam, final);
  }

  drawOverlay() {
    const el = this.overlay;
    const dpr = window.devicePixelRatio || 1;
    const w = el.clientWidth;
    const h = el.clientHeight;
    if (el.width !== Math.round(w * dpr) || el.height !== Math.round(h * dpr)) {
      el.width = Math.round(w * dpr);
      el.height = Math.round(h * dpr);
    }
    const c = el.getContext('2d');
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    c.clearRect(0, 0, w, h);
    const sx = w / this.canvas.width;
    const sy = h / this.canvas.height;
    if (this.roi && this.mode === 'hdr') {
      const [x0, y0, x1, y1] = this.roi;
      c.strokeStyle = '#fff';
      c.setLineDash([4, 3]);
      c.strokeRect(x0 * sx, y0 * sy, (x1 - x0) * sx, (y1 - y0) * sy);
      c.setLineDash([]);
    }
    if (this.roiCircle && this.mode === 'hdr') {
      // The white circle of HDR VolVis Fig. 4c.
      const r = this.roiCircle;
      c.strokeStyle = '#fff';
      c.lineWidth = 1.5;
      c.beginPath();
      c.ellipse(r.x_px * sx, r.y_px * sy, r.radius_px * sx, r.radius_px * sy, 0, 0, 2 * Math.PI);
      c.stroke();
      c.lineWidth = 1;
    }
    if (this.pickMark && this.mode === 'doppler') {
      const [px, py] = this.pickMark;
      const x = (px + 0.5) * sx;
      const y = (py + 0.5) * sy;
      c.strokeStyle = '#ff0';
      c.lineWidth = 1.5;
      c.beginPath();
      c.moveTo(x - 9, y);
      c.lineTo(x - 3, y);
      c.moveTo(x + 3, y);
      c.lineTo(x + 9, y);
      c.moveTo(x, y - 9);
      c.lineTo(x, y - 3);
      c.moveTo(x, y + 3);
      c.lineTo(x, y + 9);
      c.stroke();
    }
    if (this.camera && this.mode !== 'hdr' && this.mode !== 'relativity') this._drawTriad(c, h);
  }

  /** World x (red), y (green), z (blue) projected with the camera basis, bottom left. */
  _drawTriad(c, h) {
    const { f, r, u } = cameraBasis(this.camera);
    const cx = 34;
    const cy = h - 34;
    const len = 24;
    const axes = [
      { v: [1, 0, 0], col: '#f55', name: 'x' },
      { v: [0, 1, 0], col: '#5e5', name: 'y' },
      { v: [0, 0, 1], col: '#59f', name: 'z' },
    ];
    // Draw the axes pointing away from the viewer first.
    axes.sort((a, b) => dot(b.v, f) - dot(a.v, f));
    c.fillStyle = 'rgba(0,0,0,0.35)';
    c.beginPath();
    c.arc(cx, cy, len + 8, 0, 2 * Math.PI);
    c.fill();
    c.lineWidth = 2;
    c.font = '11px sans-serif';
    c.textAlign = 'center';
    c.textBaseline = 'middle';
    for (const a of axes) {
      const x = cx + len * dot(a.v, r);
      const y = cy - len * dot(a.v, u);
      c.strokeStyle = a.col;
      c.globalAlpha = dot(a.v, f) > 0.05 ? 0.55 : 1;
      c.beginPath();
      c.moveTo(cx, cy);
      c.lineTo(x, y);
      c.stroke();
      c.fillStyle = a.col;
      c.fillText(a.name, cx + (len + 6) * dot(a.v, r), cy - (len + 6) * dot(a.v, u));
    }
    c.globalAlpha = 1;
  }
}
