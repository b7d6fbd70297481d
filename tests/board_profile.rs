//! The board's compiled-in set-point: every shipped scenario's `[setpoint]` through the
//! build script's parser (`src/build/board_profile.rs`) into `pam_firmware::profile`, compared
//! with the closed forms of host-sim's scenario documentation evaluated here in f64; the
//! parser's refusals name the file and the key.

#[allow(dead_code)]
#[path = "../src/build/board_profile.rs"]
mod spec;

use pam_firmware::profile::SetpointProfile;
use spec::{parse_setpoint, Kind, ProfileSpec};

fn firmware_profile(s: &ProfileSpec) -> SetpointProfile {
    let [a, b, c, d] = s.f32_fields();
    match s.kind {
        Kind::Step => SetpointProfile::Step {
            initial_rad: a,
            final_rad: b,
            at_s: c,
            transition_s: d,
        },
        Kind::Ramp => SetpointProfile::Ramp {
            from_rad: a,
            to_rad: b,
            start_s: c,
            end_s: d,
        },
        Kind::Sine => SetpointProfile::Sine {
            offset_rad: a,
            amplitude_rad: b,
            freq_hz: c,
            start_s: d,
        },
    }
}

/// The set-point in f64 from the scenario documentation's formulas.
fn reference(s: &ProfileSpec, t: f64) -> f64 {
    match s.kind {
        Kind::Step => {
            let [initial_rad, final_rad, at_s, transition_s] = s.values;
            let u = if t < at_s {
                0.0
            } else if transition_s <= 0.0 {
                1.0
            } else {
                ((t - at_s) / transition_s).min(1.0)
            };
            initial_rad
                + (final_rad - initial_rad)
                    * (6.0 * u.powi(5) - 15.0 * u.powi(4) + 10.0 * u.powi(3))
        }
        Kind::Ramp => {
            let [from_rad, to_rad, start_s, end_s] = s.values;
            from_rad + (to_rad - from_rad) * ((t - start_s) / (end_s - start_s)).clamp(0.0, 1.0)
        }
        Kind::Sine => {
            let [offset_rad, amplitude_rad, freq_hz, start_s] = s.values;
            if t < start_s {
                offset_rad
            } else {
                offset_rad + amplitude_rad * (std::f64::consts::TAU * freq_hz * (t - start_s)).sin()
            }
        }
    }
}

#[test]
fn shipped_scenarios_play_on_the_board_as_specified() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios");
    let mut played = 0;
    let mut refused = 0;
    let mut paths: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    paths.sort();
    for p in paths {
        let name = p.display().to_string();
        let text = std::fs::read_to_string(&p).unwrap();
        let spec = match parse_setpoint(&name, &text) {
            Ok(s) => s,
            Err(e) => {
                // Only the random profile is refused among the shipped scenarios.
                assert!(e.contains("kind = \"random\""), "{e}");
                assert!(e.starts_with(&name), "{e}");
                refused += 1;
                continue;
            }
        };
        let fw = firmware_profile(&spec);
        // 1 kHz over 10 s, the board's time base (tick count / rate in f32).
        let mut worst = 0.0f64;
        for k in 0..10_000u32 {
            let t32 = k as f32 / 1000.0;
            let (got, want) = (fw.at(t32) as f64, reference(&spec, t32 as f64));
            // A jump at the step time may fall on either side of an f32 time stamp.
            let [_, _, at_s, transition_s] = spec.values;
            if spec.kind == Kind::Step && transition_s == 0.0 && (t32 as f64 - at_s).abs() < 1e-6 {
                continue;
            }
            worst = worst.max((got - want).abs());
        }
        assert!(worst < 1e-5, "{name}: worst {worst} rad");
        played += 1;
    }
    assert!(played >= 5, "played {played}");
    assert!(refused >= 1, "refused {refused}");
}

#[test]
fn bad_setpoint_tables_are_refused_with_file_and_key() {
    let cases = [
        ("[scenario]\nname = \"x\"\n", "no [setpoint] table"),
        ("[setpoint]\ninitial_rad = 0.0\n", "kind: missing"),
        ("[setpoint]\nkind = \"chirp\"\n", "kind = \"chirp\""),
        ("[setpoint]\nkind = \"step\"\ninitial_rad = 0.0\nfinal_rad = \"x\"\nat_s = 1.0\n", "final_rad: not a number"),
        ("[setpoint]\nkind = \"step\"\ninitial_rad = 0.0\nat_s = 1.0\n", "final_rad: missing"),
        ("[setpoint]\nkind = \"step\"\ninitial_rad = 0.0\nfinal_rad = 1.0\nat_s = 1.0\nfreq_hz = 2.0\n", "freq_hz: unknown key"),
        ("[setpoint]\nkind = \"step\"\ninitial_rad = 0.0\nfinal_rad = 1.0\nat_s = 1.0\ntransition_s = -1.0\n", "transition_s: must be >= 0"),
        ("[setpoint]\nkind = \"ramp\"\nfrom_rad = 0.0\nto_rad = 1.0\nstart_s = 2.0\nend_s = 2.0\n", "end_s: must be > start_s"),
        ("[setpoint]\nkind = \"sine\"\noffset_rad = 0.0\namplitude_rad = 1e300\nfreq_hz = 1.0\n", "amplitude_rad: not a finite f32"),
        ("[setpoint]\nkind = \"sine\"\noffset_rad = 0.0\namplitude_rad = 0.1\nfreq_hz = 0.0\n", "freq_hz: must be > 0"),
        ("[setpoint\n", "not TOML"),
    ];
    for (text, want) in cases {
        let e = parse_setpoint("s.toml", text).unwrap_err();
        assert!(e.starts_with("s.toml: "), "{e}");
        assert!(e.contains(want), "{e} (wanted {want})");
    }
    // Integers are numbers; defaults apply.
    assert_eq!(
        parse_setpoint(
            "s.toml",
            "[setpoint]\nkind = \"sine\"\noffset_rad = 0\namplitude_rad = 1\nfreq_hz = 2\n"
        ),
        Ok(ProfileSpec {
            kind: Kind::Sine,
            values: [0.0, 1.0, 2.0, 0.0]
        })
    );
}
