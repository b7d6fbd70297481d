//! `VOLUME_FNN` (in `constants.rs`) from `config/volume.toml`: the weights of the hybrid
//! model's learned chamber volume (`src/volume_fnn.rs`), written by `host-sim identify volume`.
//! The file's leading comment lines (what it was trained on, its errors) become the constant's
//! documentation, so the generated source says where its numbers come from.

use serde::Deserialize;

const FILE: &str = "config/volume.toml";
/// Units per hidden layer of the kernel (`src/volume_fnn.rs` `HIDDEN`; the generated arrays
/// have these sizes, so a mismatch does not compile either).
const HIDDEN: usize = 8;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct VolumeFile {
    volume_fnn: Net,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Net {
    hidden_units: [usize; 2],
    activation: String,
    input_mean: [f64; 4],
    input_std: [f64; 4],
    volume_offset_m3: f64,
    volume_scale_m3: f64,
    volume_floor_m3: f64,
    w1: Vec<[f64; 4]>,
    b1: Vec<f64>,
    w2: Vec<Vec<f64>>,
    b2: Vec<f64>,
    w3: Vec<f64>,
    b3: f64,
}

/// The Rust source of `VOLUME_FNN`.
pub fn constants() -> String {
    let text = super::read_text(FILE);
    let n = super::parse::<VolumeFile>(FILE, &text).volume_fnn;
    let bad =
        |field: &str, must: &str| -> ! { panic!("{FILE}: [volume_fnn] {field} must be {must}") };
    if n.hidden_units != [HIDDEN, HIDDEN] {
        bad(
            "hidden_units",
            &format!("[{HIDDEN}, {HIDDEN}] (the firmware kernel's size)"),
        );
    }
    if n.activation != "softsign" {
        bad("activation", "\"softsign\" (the firmware kernel's)");
    }
    let sizes = [
        ("w1", n.w1.len()),
        ("b1", n.b1.len()),
        ("w2", n.w2.len()),
        ("b2", n.b2.len()),
        ("w3", n.w3.len()),
    ];
    for (name, len) in sizes {
        if len != HIDDEN {
            bad(name, &format!("{HIDDEN} long (found {len})"));
        }
    }
    if n.w2.iter().any(|r| r.len() != HIDDEN) {
        bad("w2", &format!("{HIDDEN} rows of {HIDDEN}"));
    }
    let all: Vec<f64> = n
        .input_mean
        .iter()
        .chain(&n.input_std)
        .chain(n.w1.iter().flatten())
        .chain(&n.b1)
        .chain(n.w2.iter().flatten())
        .chain(&n.b2)
        .chain(&n.w3)
        .chain(
            [
                n.b3,
                n.volume_offset_m3,
                n.volume_scale_m3,
                n.volume_floor_m3,
            ]
            .iter(),
        )
        .copied()
        .collect();
    if all
        .iter()
        .any(|x| !x.is_finite() || x.abs() > f32::MAX as f64)
    {
        bad("every weight", "finite in f32");
    }
    if n.input_std.iter().any(|s| !(*s > 0.0)) {
        bad("input_std", "> 0");
    }
    if !(n.volume_scale_m3 > 0.0) {
        bad("volume_scale_m3", "> 0");
    }
    if !(n.volume_floor_m3 > 0.0) {
        bad("volume_floor_m3", "> 0");
    }
    let arr = |v: &[f64]| {
        let v: Vec<String> = v.iter().map(|&x| super::lit(x)).collect();
        format!("[{}]", v.join(", "))
    };
    let rows = |rows: Vec<String>| format!("[{}]", rows.join(", "));
    let doc: String = text
        .lines()
        .take_while(|l| l.starts_with('#') || l.trim().is_empty())
        .filter(|l| l.starts_with('#'))
        .map(|l| format!("/// {}\n", l.trim_start_matches('#').trim_start()))
        .collect();
    let fields = [
        vec![
            ("input_mean", arr(&n.input_mean)),
            ("input_inv_std", arr(&n.input_std.map(|s| 1.0 / s))),
            ("w1", rows(n.w1.iter().map(|r| arr(r)).collect())),
            ("b1", arr(&n.b1)),
            ("w2", rows(n.w2.iter().map(|r| arr(r)).collect())),
            ("b2", arr(&n.b2)),
            ("w3", arr(&n.w3)),
        ],
        super::lits(keyed!(n; b3, volume_offset_m3, volume_scale_m3, volume_floor_m3)),
    ]
    .concat();
    format!(
        "/// Hybrid-model volume network (config/volume.toml, `src/volume_fnn.rs`).\n\
         ///\n\
         {doc}{}",
        super::const_struct("VOLUME_FNN", "crate::volume_fnn::VolumeFnn", &fields)
    )
}
