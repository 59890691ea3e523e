#!/usr/bin/env bash
# Runs blueshift-gpu's criterion benches (gpu/benches/) away from the build machine, within a
# time budget, and turns criterion's results into one CSV and a short markdown table.
#
#   benches/scripts/gpu_bench.sh stage [--profile bench|release|dev] [--loaders]
#       Here, on the build machine: builds the three bench executables (`cargo bench --no-run`),
#       strips their debug info, gzips them into .device/bin/ (git-ignored) with a manifest, and
#       prints what would travel to a device machine (at most 64 MiB). --loaders also downloads
#       the Vulkan/EGL loader packages a bare device machine lacks into .device/gl/.
#   benches/scripts/gpu_bench.sh run [--small] [--with-small] [--budget SECONDS] [--out DIR]
#       Anywhere the staged executables run (no cargo, no Rust, no Python needed): runs the
#       hardware groups (tracking_paper: 2560x1440 on 512^3 x 4 with and without shadows and
#       the 1..12 channel sweep; doppler_table1; relativity_1080p; tonemap_8MP) or, with
#       --small, the groups any adapter runs (tracking_small, pool, doppler_small,
#       tonemap_small, relativity_small: lavapipe in CI), and writes gpu_bench.csv,
#       gpu_bench.md, gpu_bench.log and criterion.tar.gz to --out, else $OUT, else
#       target/gpu-bench/.
#   benches/scripts/gpu_bench.sh report CRITERION_DIR OUT_DIR [LOG]
#       Only the conversion: criterion's <group>/<bench>/new/{benchmark,estimates}.json under
#       CRITERION_DIR to OUT_DIR/gpu_bench.csv and gpu_bench.md.
#   benches/scripts/gpu_bench.sh check
#       stage --profile dev, then run --small: what CI runs after the tests.
#
# The run's exit status is 0 when every group it ran left at least one result and none
# crashed (a group cut by its share of the budget is reported as such, not as a failure).
# See gpu/README.md, "Benchmarks on a device machine".
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
STAGE="${BLUESHIFT_DEVICE_DIR:-$ROOT/.device}"
MAX_TRAVEL=$((64 * 1024 * 1024))
BENCHES="tracking doppler gpu_vs_cpu"
TMP="$(mktemp -d "${TMPDIR:-/tmp}/gpu-bench.XXXXXX")"
trap 'rm -rf "$TMP"' EXIT

die() {
    echo "gpu_bench: $*" >&2
    exit 1
}
note() { echo "gpu_bench: $*" >&2; }

usage() {
    sed -n '2,/^set -euo/p' "$0" | sed -e '$d' -e 's/^# \{0,1\}//'
}

# Bytes in the given files or folders (0 when none exist).
bytes() {
    local total=0 n p
    for p in "$@"; do
        [ -e "$p" ] || continue
        n=$(du -sb "$p" | cut -f1)
        total=$((total + n))
    done
    echo "$total"
}

mib() { awk -v b="$1" 'BEGIN { printf "%.1f MiB", b / 1048576 }'; }

# ---------------------------------------------------------------------------------------------
# stage

cmd_stage() {
    local profile=bench loaders=0
    while [ $# -gt 0 ]; do
        case "$1" in
            --profile) profile="${2:?--profile needs a value}"; shift 2 ;;
            --loaders) loaders=1; shift ;;
            -h | --help) usage; exit 0 ;;
            *) die "stage: unknown argument $1" ;;
        esac
    done
    [ "$(uname -m)" = x86_64 ] || note "warning: this machine is $(uname -m); device machines are x86-64"
    # `dev` is CI's test profile: select the benches across the workspace so that features
    # unify as in `cargo test --workspace` and no dependency is rebuilt (with -p blueshift-gpu
    # alone, clap, serde_core, smallvec, ... get other features). That also builds
    # blueshift-benches' own `doppler` bench, which is skipped below. Other profiles build
    # blueshift-gpu alone.
    local select=(-p blueshift-gpu)
    if [ "$profile" = dev ]; then
        select=(--workspace --bench tracking --bench doppler --bench gpu_vs_cpu)
    fi
    local json="$TMP/build.json"
    note "building: cargo bench --profile $profile --no-run ${select[*]}"
    local t0=$SECONDS
    (cd "$ROOT" && cargo bench --profile "$profile" --no-run --message-format=json "${select[@]}") >"$json"
    note "built in $((SECONDS - t0)) s"

    rm -rf "${STAGE:?}/bin"
    mkdir -p "$STAGE/bin"
    local exes found=0 exe name raw stripped packed
    # One JSON object a line; the bench executables are the artifacts whose target's source
    # lies in gpu/benches/.
    exes="$(grep '"reason":"compiler-artifact"' "$json" | grep '"kind":\["bench"\]' \
        | grep '"src_path":"[^"]*/gpu/benches/' \
        | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p')"
    {
        echo "commit $(git -C "$ROOT" rev-parse HEAD 2>/dev/null || echo unknown)$(git -C "$ROOT" diff --quiet HEAD 2>/dev/null || echo ' (with uncommitted changes)')"
        echo "profile $profile"
        echo "staged $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(uname -m)"
        echo "rustc $(rustc --version 2>/dev/null || echo unknown)"
    } >"$STAGE/manifest.txt"
    while IFS= read -r exe; do
        [ -n "$exe" ] || continue
        name="$(basename "$exe" | sed 's/-[0-9a-f]*$//')"
        case " $BENCHES " in *" $name "*) ;; *) continue ;; esac
        raw=$(stat -c %s "$exe")
        if command -v strip >/dev/null 2>&1; then
            strip --strip-debug -o "$STAGE/bin/$name" "$exe"
        else
            note "warning: no strip; staging $name with its debug info"
            cp "$exe" "$STAGE/bin/$name"
        fi
        stripped=$(stat -c %s "$STAGE/bin/$name")
        gzip -6 -f "$STAGE/bin/$name"
        packed=$(stat -c %s "$STAGE/bin/$name.gz")
        echo "bench $name: $(mib "$raw") built, $(mib "$stripped") stripped, $(mib "$packed") gzipped" \
            | tee -a "$STAGE/manifest.txt" >&2
        found=$((found + 1))
    done <<<"$exes"
    [ "$found" -eq 3 ] || die "stage: expected 3 bench executables ($BENCHES), found $found"

    if [ "$loaders" -eq 1 ]; then
        stage_loaders
    fi

    # What travels: tracked and untracked-not-ignored files, plus the carried .device.
    local tree staged total
    tree=$(cd "$ROOT" && git ls-files -z -co --exclude-standard | du -cb --files0-from=- 2>/dev/null | tail -1 | cut -f1)
    staged=$(bytes "$STAGE")
    total=$((tree + staged))
    echo "travel: working tree $(mib "$tree") + .device $(mib "$staged") = $(mib "$total") (limit 64 MiB)" \
        | tee -a "$STAGE/manifest.txt" >&2
    [ "$total" -lt "$MAX_TRAVEL" ] || die "stage: $(mib "$total") would travel, over the 64 MiB limit"
    note "staged in $STAGE; on the device: benches/scripts/gpu_bench.sh run (carry .device)"
}

# The loader packages a bare device machine lacks (gpu/README.md; the device tool's notes).
stage_loaders() {
    command -v apt-get >/dev/null 2>&1 || die "stage --loaders: needs apt-get"
    mkdir -p "$STAGE/gl" /tmp/amd64/partial
    local o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
    apt-get "${o[@]}" -qq update
    (cd "$STAGE/gl" && apt-get "${o[@]}" -qq download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
    note "loaders: $(cd "$STAGE/gl" && echo ./*.deb)"
}

# ---------------------------------------------------------------------------------------------
# run

# One line per bench invocation: executable;criterion filter;sampling;share of the budget;the
# groups it produces. `full` is criterion's normal sampling (a warm-up, then 10 samples);
# `quick` is criterion's --quick (no warm-up; doubles the iterations until two measurements
# agree within 5 % or the measurement time is spent; a call slower than the measurement time
# runs once), for groups whose calls can take seconds (CPU tone mapping at 8 MP, Table 1 at
# 512^2: the paper's slowest row took 79 s on a Titan RTX).
HARDWARE_RUNS=(
    "tracking;^tracking_paper/;full;36;tracking_paper"
    "doppler;^doppler_table1;quick;32;doppler_table1"
    "gpu_vs_cpu;^relativity_1080p/;full;14;relativity_1080p"
    "gpu_vs_cpu;^tonemap_8MP/;quick;18;tonemap_8MP"
)
SMALL_RUNS=(
    "tracking;^(tracking_small|pool)/;quick;30;tracking_small pool"
    "doppler;^doppler_small/;quick;40;doppler_small"
    "gpu_vs_cpu;^(tonemap_small|relativity_small)/;quick;30;tonemap_small relativity_small"
)

# Sets up Vulkan on a bare device machine: unpacks .device/gl/*.deb (else .gl/*.deb, where the
# device tool's notes put them) into / when no libvulkan is installed (as root only), and
# points the loader at NVIDIA's ICD where that file exists.
device_loaders() {
    # (grep -q would close the pipe early: ldconfig dies of SIGPIPE and pipefail fails it.)
    if ! ldconfig -p 2>/dev/null | grep libvulkan >/dev/null; then
        local debs="" d f
        for d in "$STAGE/gl" "$ROOT/.gl"; do
            if compgen -G "$d/*.deb" >/dev/null; then
                debs="$d"
                break
            fi
        done
        if [ -n "$debs" ] && [ "$(id -u)" -eq 0 ]; then
            note "no libvulkan: unpacking $debs/*.deb into /"
            for f in "$debs"/*.deb; do dpkg -x "$f" /; done
            ldconfig
        else
            note "warning: no libvulkan here (stage --loaders and carry .device to bring it)"
        fi
    fi
    local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$icd" ]; then
        export VK_DRIVER_FILES="$icd"
        export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
        note "VK_DRIVER_FILES=$icd"
    fi
}

cmd_run() {
    local small=0 with_small=0 budget="" out="${OUT:-$ROOT/target/gpu-bench}"
    while [ $# -gt 0 ]; do
        case "$1" in
            --small) small=1; shift ;;
            --with-small) with_small=1; shift ;;
            --budget) budget="${2:?--budget needs seconds}"; shift 2 ;;
            --out) out="${2:?--out needs a folder}"; shift 2 ;;
            -h | --help) usage; exit 0 ;;
            *) die "run: unknown argument $1" ;;
        esac
    done
    local runs=() full_args quick_args
    if [ "$small" -eq 1 ]; then
        runs=("${SMALL_RUNS[@]}")
        budget="${budget:-900}"
        full_args="--warm-up-time 0.2 --measurement-time 0.5"
        quick_args="--quick --measurement-time 0.3"
    else
        runs=("${HARDWARE_RUNS[@]}")
        [ "$with_small" -eq 0 ] || runs+=("${SMALL_RUNS[@]}")
        budget="${budget:-450}"
        full_args="--warm-up-time 1 --measurement-time 2"
        quick_args="--quick --measurement-time 2"
        # The hardware groups skip themselves on a software adapter; fail fast instead.
        export BLUESHIFT_GPU="${BLUESHIFT_GPU:-hardware}"
    fi
    case "$budget" in '' | *[!0-9]*) die "run: --budget takes whole seconds" ;; esac

    compgen -G "$STAGE/bin/*.gz" >/dev/null || die "run: nothing staged in $STAGE/bin (run \`$0 stage\` first)"
    device_loaders
    if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ]; then
        XDG_RUNTIME_DIR="$(mktemp -d)"
        chmod 700 "$XDG_RUNTIME_DIR"
        export XDG_RUNTIME_DIR
    fi

    local work="$TMP/run"
    mkdir -p "$work/bin" "$out"
    local b
    for b in $BENCHES; do
        gzip -dc "$STAGE/bin/$b.gz" >"$work/bin/$b"
        chmod +x "$work/bin/$b"
    done
    export CRITERION_HOME="$work/criterion"
    local log="$out/gpu_bench.log" status="$work/status.tsv"
    : >"$log"
    : >"$status"
    {
        echo "== gpu_bench run $([ "$small" -eq 1 ] && echo --small || echo hardware), budget ${budget} s, $(date -u +%Y-%m-%dT%H:%M:%SZ)"
        cat "$STAGE/manifest.txt" 2>/dev/null || true
        if command -v nvidia-smi >/dev/null 2>&1; then
            nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv 2>&1 || true
        fi
    } >>"$log"

    # Each invocation gets its weight's share of what is left, so time one leaves unused
    # goes to the ones after it.
    local start=$SECONDS weight_left=0 r
    for r in "${runs[@]}"; do
        weight_left=$((weight_left + $(echo "$r" | cut -d';' -f4)))
    done
    local exe filter sampling weight groups left cap args rc t0 stopped=0
    for r in "${runs[@]}"; do
        IFS=';' read -r exe filter sampling weight groups <<<"$r"
        if [ "$stopped" -eq 1 ]; then
            printf '%s\t%s\t%s\t%s\n' "$groups" "not run" 0 "$sampling" >>"$status"
            continue
        fi
        left=$((budget - (SECONDS - start)))
        cap=$((left * weight / weight_left))
        weight_left=$((weight_left - weight))
        if [ "$cap" -lt 5 ]; then
            note "$groups: no time left in the budget"
            printf '%s\t%s\t%s\t%s\n' "$groups" skipped 0 "$sampling" >>"$status"
            continue
        fi
        args="$full_args"
        [ "$sampling" = quick ] && args="$quick_args"
        note "$groups: $exe --bench '$filter' $args (at most $cap s)"
        echo "== $groups: $exe --bench '$filter' --noplot $args (at most $cap s)" >>"$log"
        t0=$SECONDS
        rc=0
        # shellcheck disable=SC2086
        timeout -k 10 "$cap" "$work/bin/$exe" --bench "$filter" --noplot $args >>"$log" 2>&1 || rc=$?
        note "$groups: exit $rc after $((SECONDS - t0)) s"
        printf '%s\t%s\t%s\t%s\n' "$groups" "$rc" "$((SECONDS - t0))" "$sampling" >>"$status"
        # Without the adapter the groups need, the rest would only skip too: stop here.
        if grep -q '^SKIP: no wgpu adapter' "$log"; then
            note "no wgpu adapter$([ "$small" -eq 0 ] && echo " of BLUESHIFT_GPU=$BLUESHIFT_GPU"): stopping (see $log)"
            stopped=1
        fi
        if [ "$small" -eq 0 ] && grep -q '^adapter: .*, Cpu)$' "$log"; then
            note "a software adapter was picked: the hardware groups skip themselves; stopping"
            stopped=1
        fi
    done
    echo "== total $((SECONDS - start)) s" >>"$log"

    local ok=0
    report "$CRITERION_HOME" "$out" "$log" "$status" "$((SECONDS - start))" || ok=$?
    (cd "$work" && [ -d criterion ] && tar czf "$out/criterion.tar.gz" criterion) || true
    note "wrote $out/gpu_bench.csv, gpu_bench.md, gpu_bench.log, criterion.tar.gz in $((SECONDS - start)) s"
    cat "$out/gpu_bench.md"
    return "$ok"
}

# ---------------------------------------------------------------------------------------------
# report: criterion JSON -> CSV + markdown, with awk only (the device machine has no cargo and
# need not have Python).

AWK_ROWS=$(
    cat <<'AWK'
# A criterion benchmark.json and the estimates.json and sample.json beside it -> one TSV row:
# group, bench, mean, lower, upper, median (ns), calls timed.
function str(s, key,   i, t) {
    i = index(s, "\"" key "\":\"")
    if (i == 0) return ""
    t = substr(s, i + length(key) + 4)
    return substr(t, 1, index(t, "\"") - 1)
}
function num(s, key,   i, t) {
    i = index(s, "\"" key "\":")
    if (i == 0) return ""
    t = substr(s, i + length(key) + 3)
    if (match(t, /^-?[0-9.]+([eE][-+]?[0-9]+)?/)) return substr(t, 1, RLENGTH)
    return ""
}
# The first occurrence of key inside the object that follows "name":{
function field(s, name, key,   i) {
    i = index(s, "\"" name "\":{")
    if (i == 0) return ""
    return num(substr(s, i), key)
}
FNR == 1 && NR > 1 { emit() }
{ bj = bj $0 }
END { if (NR > 0) emit() }
function slurp(path,   line, t) {
    t = ""
    while ((getline line < path) > 0) t = t line
    close(path)
    return t
}
function list(s, key, v,   i, t) {
    i = index(s, "\"" key "\":[")
    if (i == 0) return 0
    t = substr(s, i + length(key) + 4)
    return split(substr(t, 1, index(t, "]") - 1), v, ",")
}
# The calls timed: the sum of sample.json's iters. criterion's --quick reports a call slower
# than its measurement time as two samples of one call each, the second time 1 ulp above the
# first: that is one call.
function calls(s,   n, k, it, tm, sum) {
    n = list(s, "iters", it)
    if (n == 0) return ""
    if (n == 2 && list(s, "times", tm) == 2 && it[1] == it[2] && tm[2] - tm[1] <= 1e-9 * tm[1])
        return it[1] + 0
    for (k = 1; k <= n; k++) sum += it[k]
    return sum
}
function emit(   dir, e, g, b) {
    dir = prev
    if (dir == "") dir = FILENAME
    sub(/benchmark\.json$/, "", dir)
    e = slurp(dir "estimates.json")
    g = str(bj, "group_id")
    b = str(bj, "function_id")
    if (b == "") b = str(bj, "value_str")
    sub(/ \(.*\)$/, "", g)  # doppler_table1 (<adapter>) -> doppler_table1
    if (g != "" && field(e, "mean", "point_estimate") != "")
        printf "%s\t%s\t%s\t%s\t%s\t%s\t%s\n", g, b, field(e, "mean", "point_estimate"), \
            field(e, "mean", "lower_bound"), field(e, "mean", "upper_bound"), \
            field(e, "median", "point_estimate"), calls(slurp(dir "sample.json"))
    bj = ""
}
{ prev = FILENAME }
AWK
)

# report CRITERION_DIR OUT_DIR [LOG [STATUS [SECONDS]]]
report() {
    local crit="$1" out="$2" log="${3:-}" status="${4:-}" secs="${5:-}"
    mkdir -p "$out"
    local rows="$TMP/rows.tsv" adapter
    : >"$rows"
    if [ -d "$crit" ]; then
        find "$crit" -path '*/new/benchmark.json' -exec awk "$AWK_ROWS" {} + >>"$rows"
    fi
    adapter=""
    local skipped=""
    if [ -n "$log" ] && [ -f "$log" ]; then
        adapter="$(sed -n 's/^adapter: //p' "$log" | head -1)"
        skipped="$(grep -m1 '^SKIP' "$log" || true)"
    fi
    # Group order (the run's, else alphabetical) and each group's sampling, from the status.
    local order="" sampling_of="" g line s
    if [ -n "$status" ] && [ -f "$status" ]; then
        while IFS=$'\t' read -r line _ _ s; do
            for g in $line; do
                order="$order $g"
                sampling_of="$sampling_of $g=$s"
            done
        done <"$status"
    fi
    awk -F'\t' -v order="$order" -v sampling_of="$sampling_of" -v adapter="$adapter" \
        -v csv="$out/gpu_bench.csv" -v md="$out/gpu_bench.md" -v status_file="$status" \
        -v secs="$secs" -v skipped="$skipped" "$AWK_TABLE" "$rows"
}

AWK_TABLE=$(
    cat <<'AWK'
function ms(ns) { return ns == "" ? "" : sprintf(ns >= 1e9 ? "%.0f" : "%.4g", ns / 1e6) }
# The paper's figure for a row, where there is one.
function paper(g, b,   k) {
    if (g == "tracking_paper") {
        if (b ~ /512x4-2560x1440\/no-shadows$/) return "291 FPS (RTX 4090, NYX)"
        if (b ~ /512x4-2560x1440\/shadows$/) return "178 FPS (RTX 4090, NYX)"
    }
    if (g == "doppler_table1") {
        k = b
        sub(/^[^\/]*\//, "", k)
        if (k in table1) return table1[k] " ms (Titan RTX)"
    }
    return ""
}
# The CPU row a GPU row is compared with: gpu/x or gpu_f64/x -> cpu/x; x_gpu -> x_cpu.
function cpu_of(b,   k) {
    k = b
    if (sub(/^gpu(_f64)?\//, "cpu/", k)) return k
    if (sub(/_gpu$/, "_cpu", k)) return k
    return ""
}
BEGIN {
    split("shell_H_doppler_off 95 shell_H_doppler_on 278 galaxy_bb_doppler_off 84 " \
          "galaxy_bb_doppler_on 91 galaxy_H_doppler_off 561 galaxy_H_doppler_on 1190 " \
          "galaxy_bb_H_C_doppler_off 3845 galaxy_bb_H_C_doppler_on 16751 " \
          "galaxy_H_C_He_doppler_off 3523 galaxy_H_C_He_doppler_on 78933", t, " ")
    for (i = 1; i + 1 <= 20; i += 2) table1[t[i]] = t[i + 1]
    ng = split(order, og, " ")
    for (i = 1; i <= ng; i++) rank[og[i]] = i
    n = split(sampling_of, so, " ")
    for (i = 1; i <= n; i++) { split(so[i], kv, "="); samp[kv[1]] = kv[2] }
}
{
    nr++
    G[nr] = $1; B[nr] = $2; M[nr] = $3; L[nr] = $4; U[nr] = $5; D[nr] = $6; C[nr] = $7
    # A time that is no positive finite number (inf and nan compare false too) fails the run.
    if (!($3 + 0 > 0 && $3 + 0 < 1e300)) bad_times = bad_times " " $1 "/" $2
    mean[$1 "|" $2] = $3
    if (!($1 in rank)) { rank[$1] = 1000 + nr }
    count[$1]++
}
END {
    # Sort rows by group rank, then bench name (numbers compared as numbers: channels/2 < /10).
    for (i = 1; i <= nr; i++) idx[i] = i
    for (i = 2; i <= nr; i++) {
        v = idx[i]
        for (j = i - 1; j >= 1 && after(idx[j], v); j--) idx[j + 1] = idx[j]
        idx[j + 1] = v
    }
    q = "\""
    print "group,bench,mean_ms,ci_low_ms,ci_high_ms,median_ms,calls,fps,gpu_over_cpu,sampling,adapter" > csv
    print "# blueshift-gpu benches" > md
    print "" > md
    print "adapter: " (adapter == "" ? "unknown" : adapter) > md
    if (secs != "") print "run time: " secs " s" > md
    print "" > md
    print "| group | bench | mean ms | 95% CI ms | calls | FPS | GPU / CPU | paper |" > md
    print "|---|---|---|---|---|---|---|---|" > md
    for (k = 1; k <= nr; k++) {
        i = idx[k]
        g = G[i]; b = B[i]
        fps = (b ~ /^upload\//) ? "" : sprintf("%.4g", 1e9 / M[i])
        c = cpu_of(b)
        ratio = (c != "" && (g "|" c) in mean) ? sprintf("%.3g", M[i] / mean[g "|" c]) : ""
        s = (g in samp) ? samp[g] : ""
        printf "%s,%s,%s,%s,%s,%s,%s,%s,%s,%s,%s\n", g, b, ms(M[i]), ms(L[i]), ms(U[i]), \
            ms(D[i]), C[i], fps, ratio, s, q adapter q > csv
        printf "| %s | %s | %s | %s-%s | %s | %s | %s | %s |\n", g, b, ms(M[i]), ms(L[i]), \
            ms(U[i]), C[i], fps, ratio, paper(g, b) > md
    }
    if (status_file != "") {
        print "" > md
        print "| groups | exit | seconds | sampling | results |" > md
        print "|---|---|---|---|---|" > md
        while ((getline line < status_file) > 0) {
            split(line, f, "\t")
            ng = split(f[1], gs, " ")
            res = ""
            for (j = 1; j <= ng; j++) {
                res = res (j > 1 ? ", " : "") gs[j] " " (gs[j] in count ? count[gs[j]] : 0)
                if (!(gs[j] in count)) missing = missing " " gs[j]
            }
            e = f[2]
            if (e == "124" || e == "137") e = e " (cut at its budget)"
            else if (e != "0" && e != "skipped" && e != "not run") crashed = crashed " " f[1]
            printf "| %s | %s | %s | %s | %s |\n", f[1], e, f[3], f[4], res > md
        }
    }
    if (missing != "" && skipped != "") {
        print "" > md
        print "no results for" missing "; the log's first skip: " skipped > md
    }
    print "" > md
    print "sampling: full = criterion's warm-up, then 10 samples; quick = criterion's --quick " \
          "(no warm-up, 2 measurements: its CI is no confidence interval). calls: the calls " \
          "timed. GPU / CPU: the time over the same case's CPU row." > md
    if (missing != "") { print "no results:" missing > "/dev/stderr"; bad = 1 }
    if (crashed != "") { print "failed:" crashed > "/dev/stderr"; bad = 1 }
    if (nr == 0) { print "no results at all" > "/dev/stderr"; bad = 1 }
    if (bad_times != "") { print "times that are no positive number:" bad_times > "/dev/stderr"; bad = 1 }
    exit bad
}
function after(a, b) {
    if (rank[G[a]] != rank[G[b]]) return rank[G[a]] > rank[G[b]]
    return bench_after(B[a], B[b])
}
# Compares names, a trailing number as a number.
function bench_after(x, y,   px, py, nx, ny) {
    px = x; py = y; nx = ""; ny = ""
    if (match(x, /[0-9]+$/)) { px = substr(x, 1, RSTART - 1); nx = substr(x, RSTART) + 0 }
    if (match(y, /[0-9]+$/)) { py = substr(y, 1, RSTART - 1); ny = substr(y, RSTART) + 0 }
    if (px == py && nx != "" && ny != "") return nx > ny
    return x > y
}
AWK
)

cmd_report() {
    [ $# -ge 2 ] || die "report: needs CRITERION_DIR OUT_DIR [LOG]"
    report "$1" "$2" "${3:-}"
    cat "$2/gpu_bench.md"
}

cmd_check() {
    cmd_stage --profile dev
    cmd_run --small "$@"
}

case "${1:-}" in
    stage) shift; cmd_stage "$@" ;;
    run) shift; cmd_run "$@" ;;
    report) shift; cmd_report "$@" ;;
    check) shift; cmd_check "$@" ;;
    -h | --help | help) usage ;;
    *) usage >&2; exit 2 ;;
esac
