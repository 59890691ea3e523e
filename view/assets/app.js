// The page of `blueshift view`: connects to the server, routes its messages to the view,
// the editor and the panels, and exposes `window.blueshift` for the tests (PROTOCOL.md).

import { Connection, Throttle } from './net.js';
import { View3D } from './view3d.js';
import { TfEditor } from './tf.js';
import { SpectrumPlot, drawTrace, drawColourbar } from './plot.js';
import { RenderPanel, DopplerPanel, RelativityPanel, HdrPanel } from './panels.js';

const $ = (id) => document.getElementById(id);

let info = null;
let render = null;
let doppler = null;
let relativity = null;
let hdr = null;
let lastPick = null;
let drawnSeq = -1; // newest frame drawn on this connection (decoding is asynchronous)

const conn = new Connection({ onMessage: guard(onMessage), onFrame: guard(onFrame), onState });
const send = (obj) => {
  if (!conn.send(obj)) showMessage('not connected', true);
};
const camThrottle = new Throttle(send);

const view = new View3D($('view'), $('overlay'), {
  sendCamera(cam, final) {
    const msg = { type: 'camera', eye: cam.eye, target: cam.target, up: cam.up };
    if (cam.projection === 'orthographic') {
      if (Number.isFinite(cam.zoom)) msg.zoom = cam.zoom;
    } else if (Number.isFinite(cam.fov)) msg.fov = cam.fov;
    camThrottle.push(msg);
    if (final) camThrottle.flush();
  },
  onClick(x, y) {
    if (info?.mode !== 'doppler') return;
    lastPick = [x, y];
    view.pickMark = lastPick;
    view.drawOverlay();
    send({ type: 'pick', x, y });
    if (doppler) doppler.traceBtn.disabled = false;
  },
  onLook: (dx, dy, final) => relativity?.look(dx, dy, final),
  roiActive: () => Boolean(hdr?.roiActive()),
  onRoi: (roi) => hdr?.setRoi(roi),
  onKeyView: requestView,
});

const editor = new TfEditor(send);
const spectrum = new SpectrumPlot($('spectrum-canvas'));

function requestView(name) {
  view.presetRequested();
  send({ type: 'view', name });
}

let resolveReady;
const hooks = {
  ready: new Promise((r) => (resolveReady = r)),
  info: null,
  frames: 0,
  lastFrame: null,
  lastSpectrum: null,
  lastTrace: null,
  lastSaved: null,
  lastError: null,
  meanLuminance: () => view.meanLuminance(),
  send: (obj) => conn.send(obj),
  tf: {
    get channel() {
      return editor.channel;
    },
    knotScreenPos: (kind, i) => editor.knotScreenPos(kind, i),
    get fisheye() {
      return editor.fisheye;
    },
    addFocus: (center, width, magnification, transition) =>
      editor.addFocus(center, width, magnification, transition),
    get valueAxis() {
      return editor.axis.kind;
    },
    set valueAxis(kind) {
      editor.setValueAxis(kind, editor.axis.floor);
    },
    get floor() {
      return editor.axis.floor;
    },
    set floor(f) {
      editor.setValueAxis(editor.axis.kind, f);
    },
  },
};
window.blueshift = hooks;

/** Wraps a handler so that an exception shows in the message line instead of killing it. */
function guard(fn) {
  return (...args) => {
    try {
      fn(...args);
    } catch (e) {
      console.error(e);
      showMessage(`page error: ${e.message}`, true);
    }
  };
}

function showMessage(text, isError = false) {
  const m = $('message');
  m.textContent = text;
  m.classList.toggle('error', isError);
}

function onState(state) {
  $('conn').textContent = state;
  $('conn').className = state;
  $('reconnect').hidden = state !== 'closed';
  if (state === 'open') drawnSeq = -1;
  if (state === 'closed') showMessage('connection closed: press reconnect', true);
}

function onFrame(header, png) {
  createImageBitmap(png).then(
    guard((bitmap) => {
      if (header.kind === 'frame') {
        if (header.seq < drawnSeq) return; // an older frame decoded late
        drawnSeq = header.seq;
        view.drawFrame(bitmap, header.preview);
        hooks.frames += 1;
        hooks.lastFrame = {
          seq: header.seq,
          width: header.width,
          height: header.height,
          preview: header.preview,
          spp: header.spp,
        };
      } else if (header.kind === 'velocity') {
        $('panel-velocity').hidden = false;
        const cv = $('velocity');
        cv.width = bitmap.width;
        cv.height = bitmap.height;
        cv.getContext('2d').drawImage(bitmap, 0, 0);
      } else if (header.kind === 'colourbar') {
        const bar = $('colourbar');
        if (bar) drawColourbar(bar, bitmap);
      }
      bitmap.close();
    }),
    () => showMessage(`could not decode a ${header.kind} frame`, true),
  );
}

function onMessage(msg) {
  switch (msg.type) {
    case 'info':
      setupInfo(msg);
      break;
    case 'camera':
      view.setCamera(msg);
      break;
    case 'tf':
      editor.setTf(msg.channel, msg.tf);
      break;
    case 'tf_text':
      editor.download(msg);
      break;
    case 'settings':
      render?.update(msg);
      break;
    case 'doppler':
      doppler?.update(msg);
      break;
    case 'relativity':
      relativity?.update(msg);
      break;
    case 'tonemap':
      hdr?.update(msg);
      break;
    case 'status':
      showStatus(msg);
      break;
    case 'spectrum':
      hooks.lastSpectrum = msg;
      $('doppler-section').hidden = false;
      spectrum.set(msg);
      break;
    case 'trace':
      hooks.lastTrace = msg;
      drawTrace($('trace'), msg);
      break;
    case 'saved':
      hooks.lastSaved = msg;
      showSaved(msg);
      break;
    case 'error':
      hooks.lastError = msg;
      showMessage(`error${msg.request ? ` (${msg.request})` : ''}: ${msg.message}`, true);
      if (msg.request === 'tf') editor.revert();
      break;
    default:
      console.warn('unknown message', msg);
  }
}

function showStatus(st) {
  const noise = st.noise === null || st.noise === undefined ? '–' : st.noise.toExponential(2);
  const ms = Number.isFinite(st.ms) ? `${st.ms.toFixed(0)} ms/pass` : '';
  $('status').textContent =
    `pass ${st.pass} · ${st.spp}/${st.target_spp} spp · noise ${noise} · ${st.device} · ${ms} · ` +
    `${st.level ?? (st.preview ? 'preview' : 'full')}` +
    // Out-of-core volumes: the level of detail the frame sampled (0 the finest).
    `${Number.isInteger(st.lod_level) ? ` · LOD ${st.lod_level}/${st.lod_levels - 1}` : ''}` +
    `${st.done ? ' · done' : ''}`;
  render?.status(st);
}

function showSaved(msg) {
  $('panel-save').hidden = false;
  $('command').textContent = msg.command;
  $('files').replaceChildren(
    ...[...new Set([...msg.files, ...(msg.scene ? [msg.scene] : [])])].map((f) =>
      Object.assign(document.createElement('li'), { textContent: f }),
    ),
  );
  showMessage(`saved ${msg.files.length} file(s)`);
}

/** Builds the page for an `info` message (on connect and after `hello`). */
function setupInfo(msg) {
  info = msg;
  hooks.info = msg;
  $('mode').textContent = msg.mode;
  document.body.dataset.mode = msg.mode;
  view.setInfo(msg);

  const presets = $('presets');
  presets.replaceChildren(
    ...(msg.camera ? msg.views || [] : []).map((name) => {
      const b = document.createElement('button');
      b.textContent = name;
      b.title = `view preset ${name}`;
      b.addEventListener('click', () => requestView(name));
      return b;
    }),
  );

  const hasTf = msg.mode === 'tracking' && (msg.channels || []).length > 0;
  $('tf-section').hidden = !hasTf;
  if (hasTf) editor.setChannels(msg.channels);

  $('panel-render').hidden = msg.mode === 'hdr';
  render = msg.mode === 'hdr' ? null : new RenderPanel($('panel-render'), send, msg);

  $('panel-doppler').hidden = msg.mode !== 'doppler';
  $('panel-velocity').hidden = true;
  $('doppler-section').hidden = msg.mode !== 'doppler';
  doppler =
    msg.mode === 'doppler'
      ? new DopplerPanel($('panel-doppler'), send, msg.doppler, {
          onTrace: () => lastPick && send({ type: 'trace', x: lastPick[0], y: lastPick[1] }),
          onPanels: () => send({ type: 'panels' }),
        })
      : null;

  $('panel-relativity').hidden = msg.mode !== 'relativity';
  relativity =
    msg.mode === 'relativity' ? new RelativityPanel($('panel-relativity'), send, msg.relativity) : null;

  $('panel-hdr').hidden = msg.mode !== 'hdr' || !msg.tonemap;
  hdr =
    msg.mode === 'hdr' && msg.tonemap
      ? new HdrPanel($('panel-hdr'), send, msg.tonemap, {
          onRoiChange: (circle) => {
            view.roiCircle = circle;
            view.drawOverlay();
          },
        })
      : null;

  resolveReady(msg);
}

window.addEventListener('keydown', (ev) => {
  const tag = ev.target.tagName;
  if (tag === 'INPUT' || tag === 'SELECT' || tag === 'TEXTAREA' || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  if (view.key(ev)) ev.preventDefault();
});

$('save').addEventListener('click', () => {
  const name = $('save-name').value.trim();
  if (name && !/^[A-Za-z0-9_-]{1,64}$/.test(name)) {
    showMessage('a save name is 1-64 of A-Z a-z 0-9 _ -', true);
    return;
  }
  send(name ? { type: 'save', name } : { type: 'save' });
});
$('reconnect').addEventListener('click', () => conn.connect());
$('message').addEventListener('click', () => showMessage(''));
window.addEventListener('error', (ev) => showMessage(`page error: ${ev.message}`, true));
window.addEventListener('unhandledrejection', (ev) => showMessage(`page error: ${ev.reason}`, true));

conn.connect();
