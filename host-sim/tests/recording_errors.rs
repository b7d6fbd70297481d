//! Recording format: metadata kept, columns by name, errors naming file, line and field,
//! atomic writes.

use host_sim::io::recording::Channel;
use host_sim::{Recording, RecordingError};

const GOOD: &str =
    "# plant = reference-1dof.toml\n# sample_period_s = 0.001\n# operator = someone\n\
angle_deg,u_ex2,t_s,u_in2,u_in1,u_ex1,extra_col\n\
0.5,0,0.000,0,1,0,x\n\
0.6,0.25,0.001,0,1,0,y\n\
0.7,0,0.002,1,0,0,z\n";

fn err(text: &str) -> String {
    match Recording::parse(text, "run-42.csv") {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e.to_string(),
    }
}

fn assert_names(e: &str, line: u64, field: &str) {
    assert!(e.contains("run-42.csv"), "file not named: {e}");
    assert!(
        e.contains(&format!(":{line}:")),
        "line {line} not named: {e}"
    );
    assert!(
        e.contains(&format!("`{field}`")),
        "field {field} not named: {e}"
    );
}

#[test]
fn columns_in_any_order_and_metadata_kept() {
    let r = Recording::parse(GOOD, "run-42.csv").unwrap();
    assert_eq!(r.len(), 3);
    assert_eq!(r.meta("operator"), Some("someone"));
    assert_eq!(r.metadata.len(), 3);
    assert!((r.sample_period_s() - 0.001).abs() < 1e-12);
    assert_eq!(r.inputs[1].u_ex2, 0.25);
    assert_eq!(r.inputs[2].u_in2, 1.0);
    assert_eq!(r.channel(Channel::AngleDeg).unwrap(), &[0.5, 0.6, 0.7]);
    assert!(r.channel(Channel::P1Kpa).is_none());
}

#[test]
fn blanks_around_names_and_numbers_are_ignored() {
    // As spreadsheets and rig loggers write them: ", " separators, padded header names.
    let padded = GOOD
        .replace("angle_deg,u_ex2,t_s,", " angle_deg , u_ex2,t_s ,")
        .replace("0.6,0.25,0.001,", "0.6 , 0.25, 0.001,");
    let a = Recording::parse(GOOD, "run-42.csv").unwrap();
    let b = Recording::parse(&padded, "run-42.csv").unwrap();
    assert_eq!(a.inputs, b.inputs);
    assert_eq!(a.t_s, b.t_s);
    assert_eq!(a.channel(Channel::AngleDeg), b.channel(Channel::AngleDeg));
}

/// Each bad recording (`GOOD` with one text replaced) is refused with an error naming the
/// file, the line and the field.
#[test]
fn bad_recordings_name_the_file_line_and_field() {
    // (what, replaced, by, line, field)
    let extra_rows = "z\n0.8,0,0.0045,0,0,0,w\n0.9,0,0.005,0,0,0,w\n";
    let cases = [
        ("required column", "u_in2", "u_inX", 4, "u_in2"),
        ("no output", "angle_deg", "angle_x", 4, "angle_deg"),
        ("not a number", "0.6,0.25", "0.6,0.2x5", 6, "u_ex2"),
        ("NaN", "0.7,0,0.002", "NaN,0,0.002", 7, "angle_deg"),
        ("non-uniform time", "z\n", extra_rows, 8, "t_s"),
        ("opening above 1", "0,1,0,x", "0,1.5,0,x", 5, "u_in1"),
        ("period", "= 0.001", "= 0.01", 2, "sample_period_s"),
    ];
    for (what, from, to, line, field) in cases {
        assert!(GOOD.contains(from), "{what}");
        eprintln!("case: {what}");
        assert_names(&err(&GOOD.replace(from, to)), line, field);
    }
}

/// A rig logger's own file given where a recording is expected: its banner and columns are
/// no RECORDING.md columns; the error says where such a file goes (`host-sim import`).
#[test]
fn a_rig_loggers_file_is_pointed_to_import() {
    let e = err("Pr\u{fc}fstand Muskelgelenk, Messung 7\nZeit [ms];P1 [bar abs]\n0,00;6,5\n");
    assert!(
        e.contains("run-42.csv:1:")
            && e.contains("no `t_s` either")
            && e.contains("host-sim import"),
        "{e}"
    );
    // A recording that lacks one column gets no such advice.
    let e = err(&GOOD.replace("u_in2", "u_inX"));
    assert!(!e.contains("host-sim import"), "{e}");
}

#[test]
fn short_row_names_the_line() {
    let e = err(&GOOD.replace("0.6,0.25,0.001,0,1,0,y", "0.6,0.25,0.001"));
    assert!(e.contains("run-42.csv:6:"), "{e}");
}

#[test]
fn missing_file_names_the_file() {
    let e = Recording::read("/nonexistent/rec-77.csv").unwrap_err();
    assert!(matches!(e, RecordingError::Io { .. }));
    assert!(e.to_string().contains("rec-77.csv"));
}

/// [`GOOD`] written to `out.csv` in a new temporary directory: (directory, path, recording).
fn good_written() -> (tempfile::TempDir, std::path::PathBuf, Recording) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.csv");
    let r = Recording::parse(GOOD, "run-42.csv").unwrap();
    r.write(&path).unwrap();
    (dir, path, r)
}

#[test]
fn write_then_read_round_trips_and_keeps_metadata() {
    let (dir, path, r) = good_written();
    let back = Recording::read(&path).unwrap();
    assert_eq!(back, r);
    // No temporary file is left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn failed_write_keeps_the_previous_good_file() {
    let (dir, path, good) = good_written();
    let before = std::fs::read(&path).unwrap();
    let mut bad = good.clone();
    bad.inputs.pop(); // unequal column lengths: refused before anything is written
    assert!(bad.write(&path).is_err());
    // Writing into a missing directory fails without touching anything.
    assert!(good.write(dir.path().join("no/such/dir/out.csv")).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), before);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn utf8_bom_and_crlf_are_accepted() {
    let text = format!("\u{feff}{}", GOOD.replace('\n', "\r\n"));
    let r = Recording::parse(&text, "run-42.csv").unwrap();
    assert_eq!(r.len(), 3);
    assert_eq!(r.meta("plant"), Some("reference-1dof.toml"));
}

/// A recording long enough to be read in two chunks on two threads (> 256 KB of rows),
/// with `bad(k)` replacing row `k` when it returns `Some`.
fn long_recording(bad: impl Fn(usize) -> Option<String>) -> String {
    let mut text =
        String::from("# sample_period_s = 0.001\nt_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa\n");
    for k in 0..12_000 {
        match bad(k) {
            Some(row) => text.push_str(&row),
            None => text.push_str(&format!(
                "{},1,0,0.25,0,{:.6},{:.6}",
                k as f64 * 0.001,
                (k as f64 * 0.01).sin(),
                300.0 + k as f64 * 0.001
            )),
        }
        text.push('\n');
    }
    assert!(text.len() > 300_000);
    text
}

#[test]
fn a_long_recording_reads_the_same_as_row_by_row_and_names_lines_past_the_split() {
    let text = long_recording(|_| None);
    let r = Recording::parse(&text, "run-42.csv").unwrap();
    assert_eq!(r.len(), 12_000);
    for (k, &t) in r.t_s.iter().enumerate() {
        assert_eq!(t, format!("{}", k as f64 * 0.001).parse::<f64>().unwrap());
    }
    let p1 = r.channel(Channel::P1Kpa).unwrap();
    assert_eq!(
        p1[11_999],
        format!("{:.6}", 300.0 + 11_999.0 * 0.001)
            .parse::<f64>()
            .unwrap()
    );
    // Windows line ends and padded fields read the same.
    let crlf = Recording::parse(
        &text.replace('\n', "\r\n").replace(",1,0,", ", 1 ,0,"),
        "run-42.csv",
    )
    .unwrap();
    assert_eq!(crlf.t_s, r.t_s);
    assert_eq!(crlf.inputs, r.inputs);
    assert_eq!(crlf.channel(Channel::P1Kpa), r.channel(Channel::P1Kpa));
    // Row k sits on line k + 3 (one metadata line, the header). A bad row late in the file
    // (in the second chunk) is named by its own line.
    let e = err(&long_recording(|k| {
        (k == 11_000).then(|| "11,1,0,0,0,oops,1".into())
    }));
    assert_names(&e, 11_003, "angle_deg");
    let e = err(&long_recording(|k| (k == 9_000).then(|| "9,1,0".into())));
    assert!(
        e.contains(":9003:") && e.contains("3 fields, the header has 7"),
        "{e}"
    );
    // With errors in both halves, the first in the file is reported.
    let e = err(&long_recording(|k| match k {
        100 => Some("0.1,2,0,0,0,0,0".into()),
        11_000 => Some("11,1,0,0,0,oops,1".into()),
        _ => None,
    }));
    assert_names(&e, 103, "u_in1");
}

/// Two swapped rows are named as rows out of order at the row where time goes back, not as
/// a gap at the row before it (where the step first doubles); a duplicated row as repeated.
#[test]
fn swapped_or_repeated_rows_are_named_as_such() {
    let mut text = String::from("t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n");
    let rows: Vec<String> = (0..20)
        .map(|k| format!("{:.3},0,0,0,0,{}", k as f64 * 0.001, k))
        .collect();
    // Swap the rows of t = 0.010 and 0.011 s (data rows 10 and 11: file lines 12 and 13).
    let mut swapped = rows.clone();
    swapped.swap(10, 11);
    let e = err(&(text.clone() + &swapped.join("\n") + "\n"));
    assert_names(&e, 13, "t_s");
    assert!(e.contains("0.01 after 0.011"), "{e}");
    assert!(e.contains("out of order"), "{e}");
    assert!(!e.contains("non-uniform"), "{e}");
    // A repeated row: the repeat (file line 13) is named.
    let mut repeated = rows.clone();
    repeated.insert(11, rows[10].clone());
    text.push_str(&repeated.join("\n"));
    let e = err(&text);
    assert_names(&e, 13, "t_s");
    assert!(e.contains("repeated"), "{e}");
}

/// A recording that is not UTF-8: refused at the line of the first such byte (with the byte
/// and the remedy), unless only `#` comment lines are (read as Latin-1, as `import` does).
#[test]
fn a_non_utf8_recording_is_named_by_line_and_a_latin1_comment_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let head = b"# sample_period_s = 0.01\nt_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n".to_vec();
    let row = |t: &str| format!("{t},0,0,0,0,1.0\n").into_bytes();
    let mut bad = head.clone();
    bad.extend(row("0"));
    bad.extend(b"0.01,0,0,0,0,1.0\xb0\n");
    let p = dir.path().join("bad.csv");
    std::fs::write(&p, &bad).unwrap();
    let e = host_sim::Recording::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("bad.csv:4") && e.contains("0xB0") && e.contains("not UTF-8"),
        "{e}"
    );
    let mut latin = b"# operator: J\xfcrgen, 20 \xb0C\n".to_vec();
    latin.extend(head);
    latin.extend(row("0"));
    latin.extend(row("0.01"));
    latin.extend(row("0.02"));
    let p = dir.path().join("latin.csv");
    std::fs::write(&p, &latin).unwrap();
    let r = host_sim::Recording::read(&p).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.len(), 3);
}
