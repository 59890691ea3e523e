// Unit tests of the editor's pure maps (view/assets/fisheye.js) against closed forms of
// HDR VolVis Eq. 2. Run: node --test view/tests/js/
import test from 'node:test';
import assert from 'node:assert/strict';
import { Fisheye, ValueAxis, normalize, valueAtNormalized } from '../../assets/fisheye.js';

const close = (a, b, tol = 1e-12, what = '') =>
  assert.ok(Math.abs(a - b) <= tol, `${what} ${a} != ${b} (tol ${tol})`);

test('no region is the identity', () => {
  const f = new Fisheye();
  assert.equal(f.mMin, 1);
  assert.ok(f.isLinear);
  for (const t of [0, 0.1, 0.5, 0.77, 1]) {
    close(f.forward(t), t);
    close(f.inverse(t), t);
    close(f.magnification(t), 1);
  }
});

test('one region: M_min from Eq. 2 in closed form', () => {
  for (const [c, w, mc, tr] of [
    [0.5, 0.1, 4, 0.05],
    [0.3, 0.2, 2.5, 0],
    [0.7, 0.05, 10, 0.02],
  ]) {
    const f = new Fisheye([{ center: c, width: w, magnification: mc, transition: tr }]);
    // Context (1 - w - 2 tr) * M_min + w * M_c + 2 tr * (M_c + M_min) / 2 = 1.
    const mMin = (1 - mc * (w + tr)) / (1 - w - tr);
    close(f.mMin, mMin, 1e-12, 'M_min');
    close(f.totalWidth(), 1, 1e-12, 'Eq. 2');
    // Screen positions at the profile's breakpoints, integrated by hand.
    const lo = c - w / 2 - tr;
    const x0 = mMin * lo;
    const x1 = x0 + (tr * (mMin + mc)) / 2;
    const x2 = x1 + mc * w;
    const x3 = x2 + (tr * (mMin + mc)) / 2;
    close(f.forward(lo), x0, 1e-12, 'x at R_tr start');
    close(f.forward(c - w / 2), x1, 1e-12, 'x at R_c start');
    close(f.forward(c + w / 2), x2, 1e-12, 'x at R_c end');
    close(f.forward(c + w / 2 + tr), x3, 1e-12, 'x at R_tr end');
    // Magnification profile (Fig. 6b): M_c inside, M_min outside, linear across R_tr.
    close(f.magnification(c), mc);
    close(f.magnification(0.01), mMin);
    close(f.magnification(0.99), mMin);
    if (tr > 0) close(f.magnification(c - w / 2 - tr / 2), (mc + mMin) / 2, 1e-12, 'mid R_tr');
  }
});

test('forward maps 0 to 0 and 1 to 1, is monotone, and inverse undoes it', () => {
  const f = new Fisheye([
    { center: 0.2, width: 0.05, magnification: 6, transition: 0.03 },
    { center: 0.6, width: 0.1, magnification: 3, transition: 0.05 },
  ]);
  assert.equal(f.forward(0), 0);
  assert.equal(f.forward(1), 1);
  let prev = -1;
  for (let i = 0; i <= 10000; i++) {
    const t = i / 10000;
    const x = f.forward(t);
    assert.ok(x > prev, `not increasing at t = ${t}`);
    prev = x;
    close(f.inverse(x), t, 1e-12, 'inverse(forward(t))');
  }
  // Two regions: the same closed form with the sums of both.
  const mMin = (1 - 6 * (0.05 + 0.03) - 3 * (0.1 + 0.05)) / (1 - 0.08 - 0.15);
  close(f.mMin, mMin, 1e-12, 'M_min of two regions');
  // Regions come back sorted by centre.
  assert.deepEqual(
    f.regions.map((r) => r.center),
    [0.2, 0.6],
  );
});

test('a region reaching past the window end is clipped', () => {
  const f = new Fisheye([{ center: 0, width: 0.2, magnification: 3, transition: 0 }]);
  // Only [0, 0.1] lies on the axis: 0.1 * 3 + 0.9 * M_min = 1.
  close(f.mMin, (1 - 0.3) / 0.9);
  close(f.forward(0.1), 0.3);
  close(f.forward(1), 1);
});

test('invalid regions are refused', () => {
  const r = (center, width, magnification, transition) => ({
    center,
    width,
    magnification,
    transition,
  });
  assert.throws(() => new Fisheye([r(0.5, 0.1, 1, 0)]), /magnification/);
  assert.throws(() => new Fisheye([r(1.5, 0.1, 2, 0)]), /outside/);
  assert.throws(() => new Fisheye([r(0.5, 0, 2, 0)]), /width/);
  assert.throws(() => new Fisheye([r(0.5, 0.1, 2, -0.1)]), /transition/);
  assert.throws(() => new Fisheye([r(0.5, 0.1, NaN, 0)]), /finite/);
  assert.throws(() => new Fisheye([r(0.4, 0.1, 2, 0.05), r(0.5, 0.1, 2, 0.05)]), /overlap/);
  assert.throws(() => new Fisheye([r(0.5, 0.5, 3, 0)]), /no room/);
});

test('logarithmic value axis: y = 1 - log10(v) / log10(floor)', () => {
  const a = new ValueAxis('log', 1e-4);
  close(a.forward(1), 1);
  close(a.forward(1e-4), 0);
  close(a.forward(1e-2), 0.5);
  close(a.forward(1e-6), 0, 0, 'below the floor');
  close(a.forward(1e-3), 1 - -3 / -4);
  for (const v of [1e-4, 3e-3, 0.02, 0.5, 1]) close(a.inverse(a.forward(v)), v, 1e-15 + 1e-12 * v);
  const l = new ValueAxis('linear');
  close(l.forward(0.3), 0.3);
  close(l.inverse(0.3), 0.3);
  assert.throws(() => new ValueAxis('log', 0), /floor/);
  assert.throws(() => new ValueAxis('log', 1), /floor/);
});

test('data-axis normalisation, linear and log10', () => {
  close(normalize(25, [0, 100]), 0.25);
  close(valueAtNormalized(0.25, [0, 100]), 25);
  close(normalize(10, [1, 1000], 'log'), 1 / 3, 1e-15);
  close(valueAtNormalized(2 / 3, [1, 1000], 'log'), 100, 1e-12);
  close(normalize(-5, [0, 100]), 0);
  close(normalize(500, [0, 100]), 1);
});
