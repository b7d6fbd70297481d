//! The streaming replay (`io::replay_stream`, what `simulate --inputs` runs) writes exactly
//! the bytes of the whole-recording path (`Recording::read` + `simulate_recording` + the
//! sensor path + `Recording::write_to`), and leaves every file it does not take (jittered
//! stamps, any error) to that path.
//!
//! The recordings are generated here with `format!` (not with the crate's writer), with long
//! runs of identical inputs across the stream's chunk boundaries, a valve dead time and a
//! sensor lag, CRLF line ends, blank lines, an ignored text column, columns in another order,
//! and a file larger than one read block (4 MiB).

mod common;
use common::*;

use std::path::{Path, PathBuf};

use host_sim::io::recording::Recording;
use host_sim::io::replay_stream::replay_file;
use host_sim::io::replay_stream::simulate_recording;
use host_sim::sim::SolverOptions;
use host_sim::Plant;
use rand::{Rng, SeedableRng};

fn metadata(dt_s: f64) -> Vec<(String, String)> {
    vec![
        ("source".into(), "test".into()),
        ("sample_period_s".into(), format!("{dt_s}")),
    ]
}

/// The whole-recording path.
fn whole(plant: &Plant, input: &Path) -> Vec<u8> {
    let rec = Recording::read(input).unwrap();
    let opts = SolverOptions::default();
    let sim = simulate_recording(plant, &rec, &opts, |_| {}).unwrap();
    let metadata = metadata(rec.sample_period_s());
    let out = host_sim::io::replay_stream::replay_recording(plant, &rec, &sim.states, metadata);
    let mut bytes = Vec::new();
    out.write_to(&mut bytes).unwrap();
    bytes
}

/// The stream; `None` when it leaves the file to the whole-recording path.
fn streamed(plant: &Plant, input: &Path) -> Option<Vec<u8>> {
    let mut bytes = Vec::new();
    let done = replay_file(
        plant,
        input,
        &SolverOptions::default(),
        metadata,
        &mut bytes,
        &|_| {},
    )
    .unwrap();
    done.map(|d| {
        assert_eq!(d.samples, Recording::read(input).unwrap().len());
        bytes
    })
}

fn plant_with(dir: &Path, effects: &str) -> Plant {
    let text = std::fs::read_to_string(plant()).unwrap() + effects;
    let path = dir.join("plant.toml");
    std::fs::write(&path, text).unwrap();
    Plant::load(&path).unwrap()
}

/// Options for [`write_recording`].
#[derive(Clone, Copy)]
struct Gen {
    rows: usize,
    seed: u64,
    /// Mean length of a run of identical inputs, in rows.
    mean_run: usize,
    crlf: bool,
    /// An extra text column and shuffled column order.
    odd_columns: bool,
    /// Time stamp jitter, in sample periods.
    jitter: f64,
}

/// A recording at 1 kHz with random valve openings held for random runs.
fn write_recording(path: &Path, g: Gen) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(g.seed);
    let eol = if g.crlf { "\r\n" } else { "\n" };
    let mut s = format!("# source = replay_stream test{eol}# sample_period_s = 0.001{eol}");
    if g.odd_columns {
        s += &format!("note,p2_kpa,u_ex2,u_in1,t_s,u_ex1,angle_deg,u_in2{eol}");
    } else {
        s += &format!("t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,p2_kpa,f1_n,f2_n{eol}");
    }
    let mut u = [0.0f64; 4];
    let mut left = 0usize;
    for k in 0..g.rows {
        if left == 0 {
            for v in &mut u {
                *v = match rng.random_range(0..4) {
                    0 => 0.0,
                    1 => 1.0,
                    _ => (rng.random_range(0.0..1.0f64) * 1000.0).round() / 1000.0,
                };
            }
            left = rng.random_range(1..=2 * g.mean_run);
        }
        left -= 1;
        let t = k as f64 * 0.001 + g.jitter * 0.001 * rng.random_range(-1.0..1.0f64);
        let t = format!("{t:.6}");
        let y: f64 = rng.random_range(-90.0..90.0);
        if g.odd_columns {
            s += &format!(
                "row {k},{:.3},{},{},{t},{},{y:.4},{}{eol}",
                y.abs(),
                u[3],
                u[0],
                u[1],
                u[2]
            );
        } else {
            s += &format!(
                "{t},{},{},{},{},{y:.6},1.5,2.5,3.5,4.5{eol}",
                u[0], u[1], u[2], u[3]
            );
        }
        if g.crlf && k == g.rows / 3 {
            s += eol; // a blank line
        }
    }
    std::fs::write(path, s).unwrap();
}

fn gen(rows: usize, seed: u64) -> Gen {
    Gen {
        rows,
        seed,
        mean_run: 40,
        crlf: false,
        odd_columns: false,
        jitter: 0.0,
    }
}

#[test]
fn conformance_fixtures_are_streamed_byte_identical() {
    let plant = Plant::load(plant()).unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(fixture(""))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    files.sort();
    assert!(files.len() >= 4);
    for f in files {
        let s = streamed(&plant, &f).unwrap_or_else(|| panic!("{} not streamed", f.display()));
        assert!(s == whole(&plant, &f), "{}", f.display());
    }
}

#[test]
fn generated_recordings_are_streamed_byte_identical() {
    let dir = tempfile::tempdir().unwrap();
    let nominal = Plant::load(plant()).unwrap();
    let effects = plant_with(
        dir.path(),
        "\n[effects.valve_dead_time]\ndelay_s = 0.0035\n\
         \n[effects.sensor_lag]\nangle_time_constant_s = 0.01\n",
    );
    let cases = [
        // Runs far longer than a chunk of rows (1024) and the file's first 5 000 rows one run.
        (
            Gen {
                mean_run: 3000,
                ..gen(30_000, 1)
            },
            &nominal,
        ),
        (gen(20_000, 2), &effects),
        (
            Gen {
                crlf: true,
                odd_columns: true,
                mean_run: 7,
                ..gen(12_000, 3)
            },
            &effects,
        ),
        // Larger than one read block: the row count comes from a first pass over the file.
        (
            Gen {
                odd_columns: true,
                mean_run: 500,
                ..gen(120_000, 4)
            },
            &nominal,
        ),
    ];
    for (i, (g, plant)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("rec{i}.csv"));
        write_recording(&path, *g);
        let s = streamed(plant, &path).unwrap_or_else(|| panic!("case {i} not streamed"));
        assert!(s == whole(plant, &path), "case {i}");
    }
    assert!(
        std::fs::metadata(dir.path().join("rec3.csv"))
            .unwrap()
            .len()
            > 4 << 20
    );
}

#[test]
fn jittered_and_invalid_recordings_are_left_to_the_whole_recording_path() {
    let dir = tempfile::tempdir().unwrap();
    let plant = Plant::load(plant()).unwrap();
    let path = dir.path().join("rec.csv");
    // Jittered stamps: the whole-recording path integrates between them.
    write_recording(
        &path,
        Gen {
            jitter: 0.2,
            ..gen(5_000, 5)
        },
    );
    assert!(!Recording::read(&path).unwrap().is_uniform());
    assert!(streamed(&plant, &path).is_none());

    write_recording(&path, gen(5_000, 6));
    let good = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let edit = |line: usize, new: &str| {
        let mut l = lines.clone();
        l[line] = new;
        l.join("\n") + "\n"
    };
    let bad = [
        // A field that is not a number, late in the file.
        edit(4_000, "3.997,0,0,0,0,abc,1.5,2.5,3.5,4.5"),
        // An opening outside [0, 1].
        edit(100, "0.097,0,1.5,0,0,1,1.5,2.5,3.5,4.5"),
        // A gap in time.
        edit(2_000, "2.5,0,0,0,0,1,1.5,2.5,3.5,4.5"),
        // A quoted field (read by the CSV reader, not streamed).
        edit(50, "0.047,0,0,0,0,\"1\",1.5,2.5,3.5,4.5"),
        // The declared sample period disagrees with the time column.
        good.replace("# sample_period_s = 0.001", "# sample_period_s = 0.002"),
    ];
    for (i, text) in bad.iter().enumerate() {
        std::fs::write(&path, text).unwrap();
        assert!(streamed(&plant, &path).is_none(), "case {i}");
        if i != 3 {
            assert!(Recording::read(&path).is_err(), "case {i}");
        }
    }
}
