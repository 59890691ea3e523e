// Unit tests of the editor's pure helpers (view/assets/tf.js): the preview of the TF that
// the editor draws must follow tfedit's evaluation. Run: node --test view/tests/js/
import test from 'node:test';
import assert from 'node:assert/strict';
import { rgbToHsv, hsvToRgb, segmentValue, evalOpacity, evalColour } from '../../assets/tf.js';

const close = (a, b, tol = 1e-12) => assert.ok(Math.abs(a - b) <= tol, `${a} != ${b}`);

test('HSV round trips primaries and mixtures', () => {
  for (const rgb of [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.2, 0.5, 0.9], [1, 1, 1], [0, 0, 0], [0.3, 0.3, 0.1]]) {
    const back = hsvToRgb(rgbToHsv(rgb));
    rgb.forEach((c, i) => close(back[i], c, 1e-12));
  }
  assert.deepEqual(rgbToHsv([0, 0, 1]), [2 / 3, 1, 1]);
});

test('straight segments interpolate linearly; the midpoint moves the half-way point', () => {
  close(segmentValue(0, 1, 0.25, 0.5, 0), 0.25);
  // midpoint 0.25: the value is half-way at t = 0.25.
  close(segmentValue(0, 1, 0.25, 0.25, 0), 0.5);
  // sharpness 1: a step at the midpoint.
  assert.equal(segmentValue(0, 1, 0.4, 0.5, 1), 0);
  assert.equal(segmentValue(0, 1, 0.6, 0.5, 1), 1);
});

test('opacity and colour of a TF at data values, linear and log axes', () => {
  const tf = {
    domain: [0, 100],
    data_axis: 'linear',
    color_space: 'rgb',
    color: [{ x: 0, rgb: [0, 0, 1] }, { x: 100, rgb: [1, 0, 0] }],
    opacity: [{ x: 0, alpha: 0 }, { x: 50, alpha: 0.5 }, { x: 100, alpha: 0.1 }],
  };
  close(evalOpacity(tf, 25), 0.25);
  close(evalOpacity(tf, 75), 0.3);
  close(evalOpacity(tf, 150), 0.1);
  assert.deepEqual(evalColour(tf, 50), [0.5, 0, 0.5]);
  const log = { ...tf, domain: [1, 100], data_axis: 'log', opacity: [{ x: 1, alpha: 0 }, { x: 100, alpha: 1 }] };
  close(evalOpacity(log, 10), 0.5);
  const hsv = { ...tf, color_space: 'hsv' };
  // Blue to red the short way round passes magenta.
  const m = evalColour(hsv, 50);
  close(m[0], 1);
  close(m[1], 0);
  close(m[2], 1);
});
