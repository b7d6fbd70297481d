#!/usr/bin/env bash
# The recording reader's field scanner and the number formatter (host-sim/src/io/numfmt.rs)
# of this tree against those of another revision, on the 20 s conformance fixture's rows:
# best of 200 passes each, the two versions alternating. A benchmark, not a test: numfmt has
# no dependencies, so both copies are compiled as modules of one small program by rustc.
#   bash scripts/bench-numfmt.sh [REVISION]   (default: main)
set -euo pipefail
cd "$(dirname "$0")/.."
rev=${1:-main}
fixture=../shared/conformance/pulses_nominal.csv
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
strip() { sed -e '/^#\[cfg(test)\]/,$d' -e '/^\/\/!/d'; }
{
  echo '#![allow(dead_code)]'
  echo 'mod old {'; git show "$rev:host-sim/src/io/numfmt.rs" | strip; echo '}'
  echo 'mod new {'; strip < host-sim/src/io/numfmt.rs; echo '}'
  cat <<'RS'
macro_rules! passes {
    ($m:ident) => {
        (
            |data: &[u8]| -> f64 {
                let (mut i, mut acc) = (0, 0.0);
                while i < data.len() {
                    let (v, end) = $m::scan_plain_decimal(data, i);
                    acc += v.unwrap_or(1.0);
                    i = end + 1;
                }
                acc
            },
            |rows: &[[f64; 10]], buf: &mut Vec<u8>| {
                buf.clear();
                let mut tmp = [0u8; 400];
                for r in rows {
                    let mut k = $m::shortest_into(&mut tmp, r[0]).unwrap();
                    for v in &r[1..5] {
                        tmp[k] = b',';
                        k += 1 + $m::shortest_into(&mut tmp[k + 1..], *v).unwrap();
                    }
                    for v in &r[5..] {
                        tmp[k] = b',';
                        k += 1 + $m::fixed_into(&mut tmp[k + 1..], *v, 6).unwrap();
                    }
                    tmp[k] = b'\n';
                    buf.extend_from_slice(&tmp[..k + 1]);
                }
            },
        )
    };
}
fn main() {
    let path = std::env::args().nth(1).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let data_start = text.find("\n0").unwrap() + 1;
    let data = text[data_start..].as_bytes();
    let rows: Vec<[f64; 10]> = text[data_start..]
        .lines()
        .map(|l| {
            let mut r = [0.0; 10];
            for (x, f) in r.iter_mut().zip(l.split(',')) {
                *x = f.parse().unwrap();
            }
            r
        })
        .collect();
    let (scan_old, fmt_old) = passes!(old);
    let (scan_new, fmt_new) = passes!(new);
    let (mut best_scan, mut best_fmt) = ([f64::MAX; 2], [f64::MAX; 2]);
    let mut sums = [0.0; 2];
    let mut bufs = [Vec::new(), Vec::new()];
    for _ in 0..200 {
        for k in 0..2 {
            let t = std::time::Instant::now();
            sums[k] = std::hint::black_box(if k == 0 { scan_old(data) } else { scan_new(data) });
            best_scan[k] = best_scan[k].min(t.elapsed().as_secs_f64());
            let t = std::time::Instant::now();
            if k == 0 { fmt_old(&rows, &mut bufs[0]) } else { fmt_new(&rows, &mut bufs[1]) }
            std::hint::black_box(&bufs[k]);
            best_fmt[k] = best_fmt[k].min(t.elapsed().as_secs_f64());
        }
    }
    assert_eq!(sums[0].to_bits(), sums[1].to_bits(), "the scanners disagree");
    assert!(bufs[0] == bufs[1], "the formatters disagree");
    println!("{} rows, {} bytes; best of 200 passes (ms): the other revision / this tree", rows.len(), data.len());
    println!("scan every field:              {:.3} / {:.3}", best_scan[0] * 1e3, best_scan[1] * 1e3);
    println!("format every row (push_row's): {:.3} / {:.3}", best_fmt[0] * 1e3, best_fmt[1] * 1e3);
}
RS
} > "$dir/bench.rs"
rustc --edition 2021 -C opt-level=3 -C codegen-units=1 -o "$dir/bench" "$dir/bench.rs"
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg); revision $rev against this tree"
"$dir/bench" "$fixture"
