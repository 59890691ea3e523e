#!/usr/bin/env bash
# Usage: benches/scripts/golden.sh BIN OUTDIR
# Runs a fixed set of deterministic CLI jobs (tracking at fixed seeds, Doppler pwl/banded with
# and without absorption, cubes, tone mapping, relativity, spectrum, LUT, demo) into OUTDIR
# and prints the sha256 of every output. A refactoring that must not change behaviour
# compares this list before and after (`benches/reference/golden-sha256.txt` is the list of
# the engine refactoring, issue 18, re-recorded after issue 19 changed the orientation,
# the display mapping and the figures on purpose). Needs ../shared/data beside the repository.
set -u
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
B=$(realpath "$1"); O=$2; rm -rf "$O"; mkdir -p "$O"; cd "$O"
D="$ROOT/../shared/data"
run() { echo "+ $*" >> log.txt; "$B" "$@" >> log.txt 2>&1 || echo "FAILED($?): $*" >> log.txt; }
run synth galaxy g.nrrd --res 32
run render --synth galaxy --res 32 --tf builtin:viridis --method marcher --spp 16 --width 48 --height 40 --out marcher.exr --png marcher.png
run render --synth galaxy --res 32 --tf builtin:viridis --method marcher --spp 16 --precision u8 --width 48 --height 40 --out marcher_u8.exr
run render --synth three-cubes --res 32 --tf builtin:inferno --method woodcock --spp 4 --seed 7 --width 40 --height 40 --out wood.exr --png wood.png
run render --synth three-cubes --res 32 --tf builtin:inferno --method mdwt-1dda --blend mix --spp 4 --seed 7 --width 40 --height 40 --out mdwt1.exr
run render --synth channels12 --res 24 --tf builtin:cool-warm --method mdwt-ndda --blend max --spp 3 --seed 3 --width 32 --height 32 --out ndda.exr --heatmap steps --heatmap collisions
run render --synth three-cubes --res 24 --tf builtin:viridis --method mdwt-summed --spp 2 --seed 1 --width 32 --height 32 --light 1,1,1 --out summed.exr
run render --synth galaxy --res 24 --tf builtin:viridis --method woodcock --spp 2 --seed 2 --width 32 --height 32 --shading --out shaded.exr
run render "$ROOT/examples/enzo/scene.json" --width 48 --height 48 --spp 4 --out enzo.exr --png enzo.png
run render --volume g.nrrd --tf log:viridis --method marcher --spp 16 --width 40 --height 40 --out vol.exr
run render --synth three-cubes --res 24 --tf builtin:viridis --method woodcock --warmup 1 --frames 2 --width 24 --height 24 --out frames.exr
run doppler --synth galaxy --res 24 --width 40 --height 40 --out d_pwl.exr --pick 20,20 --trace 10,20
run doppler --synth galaxy --res 24 --width 40 --height 40 --absorption-factor 1 --out d_pwl_abs.exr --pick 20,20
run doppler --synth galaxy --res 24 --width 40 --height 40 --integrator banded:64 --out d_band.exr --pick 20,20
run doppler --synth galaxy --res 24 --width 40 --height 40 --integrator banded:64 --absorption-factor 1 --out d_band_abs.exr
run doppler --synth galaxy --res 24 --width 40 --height 40 --integrator banded-ec:48 --doppler relativistic --invariant --out d_bandec.exr
run doppler --synth shell --res 24 --width 32 --height 32 --velocity-factor 2 --out d_shell.exr
run doppler --synth galaxy --res 24 --width 24 --height 24 --cube cube.fits --line H-alpha --velocity-bins -150:150:30 --moments --out d_cube.exr
run doppler --synth galaxy --res 24 --width 24 --height 24 --cube cubet.fits --line H-alpha --velocity-bins -150:150:20 --thermal --axis x --out d_cubet.exr
run doppler --scene "$ROOT/scenes/enzo-moving7.json" --width 32 --height 32 --out d_enzo.exr --pick 16,16
run tonemap $D/hdr-photos/memorial.hdr --op drago --out tm_drago.png
run tonemap $D/hdr-photos/memorial.hdr --op reinhard-local --out tm_rl.png
run tonemap $D/hdr-photos/memorial.hdr --op durand --out tm_durand.png
run tonemap $D/hdr-photos/memorial.hdr --op fattal --out tm_fattal.png
run relativity --synth checker --beta 0.9 --out rel.exr
run relativity $D/envmap-kerner/KernerEnvLatLong.exr --beta 0.6 --direction 1,0,0 --out rel_env.exr
run spectrum --blackbody 5800 --lines H --radial-velocity 1e6 --json --csv spec.csv
run tf lut builtin:viridis --entries 1024 --out lut.exr
run demo demo --size 64 --res 24
find . -type f ! -name log.txt | sort | xargs sha256sum
