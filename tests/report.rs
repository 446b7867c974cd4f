//! report.html: written by run, table, campaign and `aift report`, self-contained, bounded
//! input checks; the in-memory trajectory equals the file's. (The page in a browser:
//! python/tests/test_report_browser.py.)

mod common;

use aift::report::html::{self, FolderKind};
use aift::report::run_files;
use aift::scenario::{Method, Run, TrajectoryRecorder};
use common::{aift_ok, setup, tiny_campaign};

use common::aift_in as aift;

/// Everything a page refers to is inside it: no script or style from elsewhere, no URL but
/// the SVG namespace and uPlot's own banner comment.
fn assert_self_contained(page: &str) {
    assert!(page.contains("Content-Security-Policy\" content=\"default-src 'none'"));
    assert_eq!(
        page.matches(" src=").count(),
        page.matches(" src=\"data:").count(),
        "an external resource"
    );
    assert!(!page.contains("<link"), "an external stylesheet");
    let urls: Vec<&str> = page
        .match_indices("://")
        .map(|(i, s)| (i.saturating_sub(5), s))
        .map(|(i, _)| &page[i..(i + 40).min(page.len())])
        .filter(|u| {
            !u.contains("http://www.w3.org/2000/svg")
                && !u.contains("https://github.com/leeoniya/uPlot")
        })
        .collect();
    assert!(urls.is_empty(), "URLs in the page: {urls:?}");
}

#[test]
fn run_table_and_campaign_write_a_self_contained_report() {
    let dir = tempfile::tempdir().unwrap();
    aift_ok(
        &[
            "run",
            "--set",
            "duration=9.0",
            "--method",
            "pl-always",
            "--out",
            "run",
        ],
        dir.path(),
    );
    aift_ok(
        &[
            "run",
            "--set",
            "duration=9.0",
            "--set",
            "record_every=7",
            "--out",
            "run7",
        ],
        dir.path(),
    );
    aift_ok(
        &[
            "table",
            "--set",
            "duration=9.0",
            "--methods",
            "no-ft,oracle",
            "--seeds",
            "2",
            "--out",
            "table",
        ],
        dir.path(),
    );
    std::fs::write(dir.path().join("c.toml"), tiny_campaign("report_tiny", "")).unwrap();
    aift_ok(&["campaign", "c.toml", "--out", "campaign"], dir.path());
    for (folder, kind, expect) in [
        ("run", FolderKind::Run, "Joint 2 (rad)"),
        // 9000 ticks recorded every 7th: 1286 rows, decimated on the run and by the reader alike.
        (
            "run7",
            FolderKind::Run,
            "evenly spaced rows of the run's 1286 recorded rows",
        ),
        ("table", FolderKind::Table, "Healthy-joint MSE per seed"),
        ("campaign", FolderKind::Campaign, "href=\"#cell-0\""),
    ] {
        let path = dir.path().join(folder);
        assert_eq!(FolderKind::detect(&path).unwrap(), kind);
        let page = std::fs::read_to_string(path.join(html::REPORT)).unwrap();
        assert_self_contained(&page);
        assert!(page.contains(expect), "{folder}: no {expect:?}");
        if kind == FolderKind::Campaign {
            // One seed: no cell can favour either method; the matrix counts 0 of every cell.
            let doc: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(path.join("campaign.json")).unwrap())
                    .unwrap();
            let cells = doc["cells"].as_array().unwrap().len();
            let start = page
                .find("id=\"comparisons\"")
                .expect("a comparisons section");
            let section = &page[start..start + page[start..].find("</table>").unwrap()];
            assert_eq!(
                section
                    .matches(&format!("<td class=num>0/{cells}</td>"))
                    .count(),
                2,
                "{section}"
            );
        }
        // `aift report` writes the same page again from the folder's files (for a run, from
        // the trajectory file instead of the run's recorder: the same rows).
        std::fs::remove_file(path.join(html::REPORT)).unwrap();
        let out = aift_ok(&["report", folder, "--json"], dir.path());
        let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(doc["kind"], kind.name());
        let again = std::fs::read_to_string(path.join(html::REPORT)).unwrap();
        assert_eq!(
            again, page,
            "{folder}: aift report differs from the page the run wrote"
        );
    }
}

#[test]
fn report_refuses_what_is_not_an_aift_folder() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("empty")).unwrap();
    std::fs::write(d.join("file.txt"), "x").unwrap();
    std::fs::create_dir(d.join("bad")).unwrap();
    std::fs::write(d.join("bad/table.json"), "{\"rows\": []}").unwrap();
    std::fs::create_dir(d.join("garbage")).unwrap();
    std::fs::write(d.join("garbage/summary.json"), "{\"format_version\": 2}").unwrap();
    std::fs::write(d.join("garbage/trajectory.csv"), "t,q1\n0.0,abc\n").unwrap();
    for (arg, needle) in [
        ("empty", "not a run, table or campaign folder"),
        ("file.txt", "not a folder"),
        ("missing", "cannot read"),
        ("bad", "`format_version`: missing"),
        ("garbage", "summary.json: `scenario`: missing"),
    ] {
        let out = aift(&["report", arg], d);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{arg}: {err}");
        assert!(err.contains(needle) && err.contains(arg), "{arg}: {err}");
        assert!(!d.join(arg).join("report.html").exists());
    }
}

#[test]
fn in_memory_trajectory_equals_the_file() {
    let s = setup(
        "paper_encoder_freeze.toml",
        &["duration=3.0", "record_every=7"],
    );
    let (_, summary, columns) =
        run_files::run_in_memory(Run::new(&s, Method::PlAlways).seed(4)).expect("runs");
    let dir = tempfile::tempdir().unwrap();
    let staged =
        aift::fsio::Staged::begin(&dir.path().join("r"), aift::fsio::OutputKind::Folder, false)
            .unwrap();
    let result = run_files::run_staged(&staged, Run::new(&s, Method::PlAlways).seed(4)).unwrap();
    staged.commit().unwrap();
    let file = TrajectoryRecorder::read_csv(&dir.path().join("r/trajectory.csv")).unwrap();
    assert_eq!(file.header, columns.names());
    assert_eq!(file.rows.len(), columns.rows());
    assert_eq!(columns.rows(), 3000usize.div_ceil(7));
    for (c, column) in columns.columns().iter().enumerate() {
        for (r, v) in column.iter().enumerate() {
            let f = file.rows[r][c];
            assert!(
                f.to_bits() == v.to_bits() || (f.is_nan() && v.is_nan()),
                "{} row {r}",
                file.header[c]
            );
        }
    }
    assert_eq!(summary["mse_faulty"], serde_json::json!(result.mse_faulty));
    // The decimating reader keeps every k-th row, bounded.
    let (few, total) =
        TrajectoryRecorder::read_csv_decimated(&dir.path().join("r/trajectory.csv"), 100).unwrap();
    assert_eq!(total as usize, file.rows.len());
    assert!(few.rows.len() < 100 && few.rows.len() >= 50);
    let bits = |r: &[f64]| r.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    for (i, row) in few.rows.iter().enumerate() {
        assert_eq!(bits(row), bits(&file.rows[i * few.stride() as usize]));
    }
}

#[test]
fn in_memory_trajectory_is_bounded_before_the_run() {
    let s = setup(
        "paper_healthy.toml",
        // Within the trajectory file's bound (4 GiB), beyond the in-memory one (2^27 values).
        &["duration=4100.0", "plant.engine=\"articulated\""],
    );
    let err = run_files::run_in_memory(Run::new(&s, Method::NoFt).seed(1)).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("record_every") && msg.contains("paper_healthy.toml"),
        "{msg}"
    );
}
