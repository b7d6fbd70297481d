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
    println!("cargo:rerun-if-changed={FILE}");
    let text = std::fs::read_to_string(FILE).unwrap_or_else(|e| panic!("{FILE}: cannot read: {e}"));
    let f: VolumeFile = toml::from_str(&text).unwrap_or_else(|e| panic!("{FILE}: {e}"));
    let n = f.volume_fnn;
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
    let lit = |x: f64| format!("{:?}_f32", x as f32);
    let arr = |v: &[f64]| {
        format!(
            "[{}]",
            v.iter().map(|x| lit(*x)).collect::<Vec<_>>().join(", ")
        )
    };
    let doc: String = text
        .lines()
        .take_while(|l| l.starts_with('#') || l.trim().is_empty())
        .filter(|l| l.starts_with('#'))
        .map(|l| format!("/// {}\n", l.trim_start_matches('#').trim_start()))
        .collect();
    format!(
        "/// Hybrid-model volume network (config/volume.toml, `src/volume_fnn.rs`).\n\
         ///\n\
         {doc}\
         pub const VOLUME_FNN: crate::volume_fnn::VolumeFnn = crate::volume_fnn::VolumeFnn {{\n\
         \x20   input_mean: {},\n\
         \x20   input_inv_std: {},\n\
         \x20   w1: [{}],\n\
         \x20   b1: {},\n\
         \x20   w2: [{}],\n\
         \x20   b2: {},\n\
         \x20   w3: {},\n\
         \x20   b3: {},\n\
         \x20   volume_offset_m3: {},\n\
         \x20   volume_scale_m3: {},\n\
         \x20   volume_floor_m3: {},\n\
         }};\n",
        arr(&n.input_mean),
        arr(&n.input_std.map(|s| 1.0 / s)),
        n.w1.iter().map(|r| arr(r)).collect::<Vec<_>>().join(", "),
        arr(&n.b1),
        n.w2.iter().map(|r| arr(r)).collect::<Vec<_>>().join(", "),
        arr(&n.b2),
        arr(&n.w3),
        lit(n.b3),
        lit(n.volume_offset_m3),
        lit(n.volume_scale_m3),
        lit(n.volume_floor_m3),
    )
}
