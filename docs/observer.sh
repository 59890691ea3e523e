#!/usr/bin/env bash
# docs/observer.png: the synthetic galaxy (64^3, inclined 40 degrees, perspective at 50
# degrees) seen at rest, flying into it at beta 0.5 and at beta 0.9 (columns). Top row: true
# colour (the gas's own velocities, black body and H); bottom row: velocity-coded (the gas's
# velocities x30, so its rotation shows as colour). Each panel is exposed at its 99th
# percentile (the searchlight's brightening is not shown). Python's Pillow stacks the panels.
# Run from the repository root after `cargo build --release`.
set -euo pipefail
B=${BLUESHIFT:-target/release/blueshift}
out=$(mktemp -d)
for f in 1 30; do
  for beta in 0 0.5 0.9; do
    "$B" doppler --synth galaxy --res 64 --inclination 40 --fov 50 --width 192 --height 192 \
      --species bb,H --velocity-factor "$f" --doppler relativistic --beta "$beta" \
      --out "$out/v${f}_b$beta.exr" 2>/dev/null
  done
done
python3 - "$out" docs/observer.png <<'PY'
import sys
from PIL import Image, ImageDraw
d = sys.argv[1]
betas = ("0", "0.5", "0.9")
rows = (("1", "true colour"), ("30", "velocity-coded (x30)"))
tile, pad = 192, 22
out = Image.new("RGB", (3 * tile, 2 * (tile + pad)), "white")
draw = ImageDraw.Draw(out)
for r, (f, name) in enumerate(rows):
    for c, b in enumerate(betas):
        x, y = c * tile, r * (tile + pad)
        draw.text((x + 4, y + 5), f"beta {b}, {name}", fill="black")
        out.paste(Image.open(f"{d}/v{f}_b{b}.png").convert("RGB"), (x, y + pad))
out.save(sys.argv[2], optimize=True)
PY
echo "wrote docs/observer.png"
