//! The atomic writer's transaction: staged outputs appear only on commit and vanish (with
//! the directories the run created) when it is dropped. One test in its own process: the
//! stage is process-wide.

use host_sim::io::atomic::{create_dir_all, write_bytes, Transaction};

/// The content of `path` after host-sim's mark line, which every write puts first.
fn body(path: &std::path::Path) -> String {
    let t = std::fs::read_to_string(path).unwrap();
    let mark = format!("# generator = {}\n", host_sim::output::MARK);
    t.strip_prefix(&mark)
        .unwrap_or_else(|| panic!("no mark in {t:?}"))
        .to_string()
}

#[test]
fn staged_files_appear_on_commit_and_vanish_on_drop() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.csv");
    std::fs::write(&a, "old").unwrap();
    write_bytes(&a, b"direct").unwrap();
    assert_eq!(body(&a), "direct");

    let tx = Transaction::begin();
    write_bytes(&a, b"new").unwrap();
    let sub = dir.path().join("x/y");
    create_dir_all(&sub).unwrap();
    write_bytes(&sub.join("b.json"), b"{}").unwrap();
    assert_eq!(body(&a), "direct");
    drop(tx);
    assert_eq!(body(&a), "direct");
    assert!(!dir.path().join("x").exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

    let tx = Transaction::begin();
    write_bytes(&a, b"first").unwrap();
    write_bytes(&a, b"second").unwrap();
    let png = dir.path().join("p.png");
    host_sim::io::atomic::write_via_path(&png, |tmp| {
        assert_eq!(tmp.extension().unwrap(), "png");
        std::fs::write(tmp, b"img")
    })
    .unwrap();
    assert!(!png.exists());
    tx.commit().unwrap();
    assert_eq!(body(&a), "second");
    assert_eq!(body(&png), "img");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}
