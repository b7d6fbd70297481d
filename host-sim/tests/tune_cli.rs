//! `host-sim tune`: argument errors name the argument and its allowed range, exit with
//! status 2 and leave the output untouched. (The search itself takes minutes; its procedure is
//! checked by the local-optimum tests of `control_compare.rs` on the file it wrote.)

mod common;
use common::*;

#[test]
fn bad_tune_arguments_are_refused_without_touching_the_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("control.toml");
    std::fs::write(&out, "# generator = host-sim (an earlier run)\nprevious\n").unwrap();
    for (args, want) in [
        (vec!["--threads", "0"], "must be within 1..=256, got 0"),
        (vec!["--threads", "300"], "must be within 1..=256, got 300"),
        (
            vec!["--transition-s", "5"],
            "must be a number of seconds within [0, 2], got 5",
        ),
        (
            vec!["--setpoint-cutoff-hz", "0"],
            "--setpoint-cutoff-hz 0: allowed 1..=500 Hz",
        ),
        (vec!["--cascade-start", "1,2"], "--cascade-start 1,2"),
        // A start the gains file could not load (it bounds kp at 1e4 N m/rad).
        (
            vec!["--cascade-start", "1e9,1,1"],
            "position_kp_nm_per_rad 1000000000 is above 1e4",
        ),
        // Milliseconds typed with their unit: the message says to give plain seconds.
        (
            vec!["--transition-s", "150ms"],
            "give seconds within [0, 2] as a plain number",
        ),
        // A negative number is a value out of range, not an unknown argument.
        (
            vec!["--transition-s", "-1"],
            "must be a number of seconds within [0, 2], got -1",
        ),
        // The outer loops below 200 Hz at the 1 kHz tick.
        (
            vec!["--outer-period-ticks", "6"],
            "invalid value '6' for '--outer-period-ticks <N>': outside the allowed range 1..=5",
        ),
        (
            vec!["--outer-period-ticks", "0"],
            "invalid value '0' for '--outer-period-ticks <N>': outside the allowed range 1..=5",
        ),
        (
            vec!["--pressure-ff", "--ff-update-ticks", "101"],
            "invalid value '101' for '--ff-update-ticks <N>': outside the allowed range 1..=100",
        ),
        (
            vec!["--pressure-ff", "--ff-update-ticks", "-3"],
            "outside the allowed range 1..=100",
        ),
        (
            vec!["--pressure-ff", "--ff-update-ticks", "two"],
            "not a whole number of ticks; allowed 1..=100",
        ),
        // The feed-forward's period means nothing without it.
        (vec!["--ff-update-ticks", "2"], "--pressure-ff"),
    ] {
        let mut rest: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"--out", &out];
        rest.extend(args.iter().map(|a| a as &dyn AsRef<std::ffi::OsStr>));
        let err = exits(2, &on_plant("tune", &plant(), &rest));
        assert!(err.contains(want), "{args:?}: {err}");
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            "# generator = host-sim (an earlier run)\nprevious\n"
        );
    }
    // The plant file as the output is refused before any work: the gains would replace it.
    let plant_copy = dir.path().join("plant.toml");
    std::fs::copy(plant(), &plant_copy).unwrap();
    let before = std::fs::read(&plant_copy).unwrap();
    let r = on_plant("tune", &plant_copy, &[&"--out", &plant_copy]);
    assert_eq!(r.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&r.stderr).contains("refusing to overwrite an input"),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert_eq!(std::fs::read(&plant_copy).unwrap(), before);
    // A missing plant file is named.
    let r = on_plant("tune", &"no/such/plant.toml", &[&"--out", &out]);
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("no/such/plant.toml"));
}
