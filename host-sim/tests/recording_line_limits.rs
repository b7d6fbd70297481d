//! Line-length limits of the recording reader: a metadata or header line longer than
//! `MAX_HEAD_LINE_BYTES` or a data row longer than `MAX_DATA_LINE_BYTES` is refused with
//! the file, the line and the limit, exit status 2, nothing written, and without reading the
//! long line into memory first (a 60 MB header line once took the reader to about 950 MB).

mod common;
use common::*;
use std::io::Write as _;
use std::path::Path;

use host_sim::io::recording::{MAX_DATA_LINE_BYTES, MAX_HEAD_LINE_BYTES};
use host_sim::{Recording, RecordingError};

const HEADER: &str = "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,note";

/// Writes a recording: one metadata line, the header with its last column named by
/// `header_tail` bytes of `n` after `note`, then `rows` rows of 1 ms; row `long_row` (0-based)
/// has `long_note` bytes in its note field, the others one byte.
fn write_recording(
    path: &Path,
    header_tail: usize,
    rows: usize,
    long_row: usize,
    long_note: usize,
) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    writeln!(f, "# sample_period_s = 0.001").unwrap();
    f.write_all(HEADER.as_bytes()).unwrap();
    let piece = vec![b'n'; 1 << 20];
    let mut left = header_tail;
    while left > 0 {
        let k = left.min(piece.len());
        f.write_all(&piece[..k]).unwrap();
        left -= k;
    }
    f.write_all(b"\n").unwrap();
    for k in 0..rows {
        let u = if (k / 50) % 2 == 0 {
            "1,0,0,1"
        } else {
            "0,1,1,0"
        };
        let note = if k == long_row {
            "w".repeat(long_note)
        } else {
            "w".into()
        };
        writeln!(f, "{:.3},{u},0.0,{note}", k as f64 * 1e-3).unwrap();
    }
    f.flush().unwrap();
}

/// Status 2, no panic, every `needles` in stderr.
fn refused(r: &std::process::Output, needles: &[&str]) {
    let err = text(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "stderr:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "`{n}` not in:\n{err}");
    }
}

/// The largest resident set of the children this process has waited for, in bytes.
#[cfg(target_os = "linux")]
fn children_max_rss_bytes() -> u64 {
    // SAFETY: getrusage fills the zeroed struct it is given.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    assert_eq!(unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut u) }, 0);
    u.ru_maxrss as u64 * 1024
}

#[test]
fn a_60_mb_header_line_is_refused_with_its_line_and_the_limit_without_reading_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("huge-header.csv");
    write_recording(&input, 60_000_000, 200, usize::MAX, 0);
    let out = dir.path().join("out.csv");
    let r = on_plant("simulate", &plant(), &[&"--inputs", &input, &"--out", &out]);
    let limit = MAX_HEAD_LINE_BYTES.to_string();
    refused(&r, &["huge-header.csv:2:", &limit]);
    assert!(!out.exists(), "an output was written");
    // The other tests of this file run small files: the largest child is this one (or
    // smaller). The whole line alone would be 60 MB.
    #[cfg(target_os = "linux")]
    {
        let rss = children_max_rss_bytes();
        assert!(rss < 40_000_000, "a child used {rss} B");
    }

    // The library reader names the same line.
    match Recording::read(&input) {
        Err(RecordingError::Line {
            line: 2, message, ..
        }) => {
            assert!(message.contains(&limit), "{message}")
        }
        other => panic!("expected the header line refused, got {other:?}"),
    }
}

#[test]
fn a_data_row_over_the_limit_is_refused_and_one_under_it_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let long = dir.path().join("long-row.csv");
    // Row 3 (0-based) is on line 6: one metadata line, the header, rows 0-2.
    write_recording(&long, 0, 200, 3, MAX_DATA_LINE_BYTES + 1);
    let out = dir.path().join("out.csv");
    let r = on_plant("simulate", &plant(), &[&"--inputs", &long, &"--out", &out]);
    refused(&r, &["long-row.csv:6:", &MAX_DATA_LINE_BYTES.to_string()]);
    assert!(!out.exists(), "an output was written");
    let r = host_sim(&[&"fit", &long, &long]);
    refused(&r, &["long-row.csv:6:", &MAX_DATA_LINE_BYTES.to_string()]);

    // A row just under the limit (its note fills it) is an ordinary row.
    let fine = dir.path().join("fine.csv");
    let row_bytes = "0.003,1,0,0,1,0.0,".len();
    write_recording(&fine, 0, 200, 3, MAX_DATA_LINE_BYTES - row_bytes);
    let r = on_plant("simulate", &plant(), &[&"--inputs", &fine, &"--out", &out]);
    ok(&r);
    let rec = Recording::read(&out).unwrap();
    assert_eq!(rec.len(), 200);
}

#[test]
fn a_long_metadata_line_in_text_given_to_the_parser_is_refused() {
    let text = format!(
        "# note = {}\n{HEADER}\n0,1,0,0,1,0.0,a\n0.001,1,0,0,1,0.0,b\n",
        "m".repeat(MAX_HEAD_LINE_BYTES)
    );
    match Recording::parse(&text, "meta.csv") {
        Err(RecordingError::Line {
            line: 1, message, ..
        }) => {
            assert!(
                message.contains(&MAX_HEAD_LINE_BYTES.to_string()),
                "{message}"
            )
        }
        other => panic!("expected the metadata line refused, got {other:?}"),
    }
}
