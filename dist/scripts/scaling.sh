#!/usr/bin/env bash
# Strong scaling of `--distributed data` on one machine: the same Doppler render (with
# absorption, exact compositing) and the same marcher render on 1..4 ranks under
# `mpirun --oversubscribe` (and Woodcock with forwarded rays), wall time of the whole job (MPI start-up included), against the
# single process without MPI. Each rank runs one rendering thread (RAYON_NUM_THREADS=1),
# so the ranks are the only parallelism. Usage: dist/scripts/scaling.sh [BLUESHIFT_BINARY] [RES] [SIZE]
# (the binary must be built with --features mpi).
set -euo pipefail
BIN=${1:-target/debug/blueshift}
RES=${2:-64}
SIZE=${3:-128}
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
run() { # label, command...
    local label=$1; shift
    local t0 t1
    t0=$(date +%s.%N)
    "$@" >/dev/null 2>"$dir/err" || { cat "$dir/err"; exit 1; }
    t1=$(date +%s.%N)
    python3 -c "print('$label', round($t1 - $t0, 3))"
}
doppler=(doppler --synth galaxy --res "$RES" --species bb,H,C --absorption-factor 5
         --velocity-factor 30 --width "$SIZE" --height "$SIZE" --device cpu)
marcher=(render --synth three-cubes --res "$RES" --tf builtin:viridis --method marcher
         --density-scale 1 --width "$SIZE" --height "$SIZE" --device cpu)
# Woodcock with rays forwarded between the ranks' pieces (bit-identical to the single process).
woodcock=(render --synth three-cubes --res "$RES" --tf builtin:viridis --method woodcock
          --density-scale 4 --spp 256 --width "$SIZE" --height "$SIZE" --device cpu)
for what in doppler marcher woodcock; do
    declare -n args=$what
    run "$what single" "$BIN" "${args[@]}" --out "$dir/s.exr"
    for n in 1 2 3 4; do
        RAYON_NUM_THREADS=1 run "$what np=$n" mpirun --oversubscribe -np "$n" "$BIN" \
            "${args[@]}" --distributed data --out "$dir/d$n.exr"
    done
    RAYON_NUM_THREADS=1 run "$what single-1-thread" "$BIN" "${args[@]}" --out "$dir/t.exr"
done
