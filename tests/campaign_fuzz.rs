//! Structure-aware fuzzing of campaign files and of `records.json` (issue 30): random edits of a
//! valid file's tree (values replaced by others of every type, huge, negative, NaN, long or
//! hostile strings; entries removed, duplicated or repeated many times; lists emptied) go
//! through parsing and checking, and, when accepted, through the grid's expansion or the merge.
//! Each ends in a value or an error; never a panic, and what is accepted is bounded (cells,
//! jobs), so nothing allocates in proportion to a number in the file.

mod common;

use std::path::{Path, PathBuf};

use aift::scenario::campaign::{
    Campaign, CampaignConfig, CampaignRecords, MAX_CELLS, MAX_JOBS, Shard, check_records, merge,
    run_campaign,
};
use proptest::prelude::*;

/// One edit of a tree: where (an index into its nodes, taken modulo their count) and what.
#[derive(Clone, Debug)]
enum Edit {
    Replace(usize, Scalar),
    Remove(usize),
    Repeat(usize, usize),
    Empty(usize),
}

#[derive(Clone, Debug)]
enum Scalar {
    Int(i64),
    Float(f64),
    Text(String),
    Bool(bool),
}

fn scalar() -> impl Strategy<Value = Scalar> {
    prop_oneof![
        prop_oneof![
            Just(0i64),
            Just(-1),
            Just(1),
            Just(2),
            Just(1 << 40),
            Just(i64::MAX),
            Just(i64::MIN),
            Just(100_000),
            Just(10_000_000)
        ]
        .prop_map(Scalar::Int),
        prop_oneof![
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(-1e300),
            Just(1e-300),
            Just(0.5),
            Just(-0.0)
        ]
        .prop_map(Scalar::Float),
        prop_oneof![
            Just(String::new()),
            Just("../../etc".to_string()),
            Just("a/b".to_string()),
            Just(".hidden".to_string()),
            Just("x".repeat(5000)),
            Just("enc*".to_string()),
            Just("cam".to_string()),
            Just("hybrid".to_string()),
            Just("freeze".to_string()),
            Just("rest-then-motion".to_string()),
        ]
        .prop_map(Scalar::Text),
        any::<bool>().prop_map(Scalar::Bool),
    ]
}

fn edits() -> impl Strategy<Value = Vec<Edit>> {
    let edit = prop_oneof![
        4 => (any::<usize>(), scalar()).prop_map(|(i, s)| Edit::Replace(i, s)),
        2 => any::<usize>().prop_map(Edit::Remove),
        2 => (any::<usize>(), prop_oneof![Just(2usize), Just(3), Just(50), Just(2000)])
            .prop_map(|(i, n)| Edit::Repeat(i, n)),
        1 => any::<usize>().prop_map(Edit::Empty),
    ];
    prop::collection::vec(edit, 1..5)
}

/// A tree both formats map onto.
trait Tree: Clone {
    /// Child slots of this node: (key for objects, or index).
    fn children_mut(&mut self) -> Vec<&mut Self>;
    fn count(&mut self) -> usize {
        1 + self
            .children_mut()
            .into_iter()
            .map(|c| c.count())
            .sum::<usize>()
    }
    fn from_scalar(s: &Scalar) -> Self;
    /// Removes child `k` of this node (object key or array element); false if none.
    fn remove_child(&mut self, k: usize) -> bool;
    /// Repeats child `k` `n` times (arrays) ; false if not an array.
    fn repeat_child(&mut self, k: usize, n: usize) -> bool;
    fn empty(&mut self);
}

/// The `i`-th node in pre-order (modulo the count) and its parent's child index.
fn apply<T: Tree>(root: &mut T, edit: &Edit) {
    let n = root.count();
    let (Edit::Replace(i, _) | Edit::Remove(i) | Edit::Repeat(i, _) | Edit::Empty(i)) = edit;
    let target = i % n;
    fn walk<T: Tree>(node: &mut T, target: usize, seen: &mut usize, edit: &Edit) -> bool {
        let here = *seen;
        *seen += 1;
        if here == target {
            match edit {
                Edit::Replace(_, s) => *node = T::from_scalar(s),
                Edit::Empty(_) => node.empty(),
                _ => {}
            }
            return true;
        }
        let mut children = node.children_mut();
        let mut hit = None;
        for (k, c) in children.iter_mut().enumerate() {
            if *seen == target && matches!(edit, Edit::Remove(_) | Edit::Repeat(..)) {
                hit = Some(k);
                break;
            }
            if walk(*c, target, seen, edit) {
                return true;
            }
        }
        drop(children);
        if let Some(k) = hit {
            match edit {
                Edit::Remove(_) => {
                    node.remove_child(k);
                }
                Edit::Repeat(_, n) => {
                    node.repeat_child(k, *n);
                }
                _ => {}
            }
            return true;
        }
        false
    }
    let mut seen = 0;
    walk(root, target, &mut seen, edit);
}

/// The tree operations on one document type: its map and list variants and how a scalar is
/// written in it (TOML and JSON differ only there).
macro_rules! impl_tree {
    ($value:ty, $map:path, $list:path, $from_scalar:expr) => {
        impl Tree for $value {
            fn children_mut(&mut self) -> Vec<&mut Self> {
                match self {
                    $map(m) => m.iter_mut().map(|(_, v)| v).collect(),
                    $list(a) => a.iter_mut().collect(),
                    _ => vec![],
                }
            }
            fn from_scalar(s: &Scalar) -> Self {
                $from_scalar(s)
            }
            fn remove_child(&mut self, k: usize) -> bool {
                match self {
                    $map(m) => {
                        let key = m.keys().nth(k).cloned();
                        key.is_some_and(|key| m.remove(&key).is_some())
                    }
                    $list(a) if k < a.len() => {
                        a.remove(k);
                        true
                    }
                    _ => false,
                }
            }
            fn repeat_child(&mut self, k: usize, n: usize) -> bool {
                match self {
                    $list(a) if k < a.len() => {
                        let item = a[k].clone();
                        for _ in 1..n {
                            a.push(item.clone());
                        }
                        true
                    }
                    _ => false,
                }
            }
            fn empty(&mut self) {
                match self {
                    $map(m) => m.clear(),
                    $list(a) => a.clear(),
                    _ => {}
                }
            }
        }
    };
}

impl_tree!(
    toml::Value,
    toml::Value::Table,
    toml::Value::Array,
    |s: &Scalar| match s {
        Scalar::Int(i) => toml::Value::Integer(*i),
        Scalar::Float(f) => toml::Value::Float(*f),
        Scalar::Text(t) => toml::Value::String(t.clone()),
        Scalar::Bool(b) => toml::Value::Boolean(*b),
    }
);

impl_tree!(
    serde_json::Value,
    serde_json::Value::Object,
    serde_json::Value::Array,
    // JSON has no NaN: serde_json writes null for it.
    |s: &Scalar| match s {
        Scalar::Int(i) => serde_json::Value::from(*i),
        Scalar::Float(f) => serde_json::Number::from_f64(*f)
            .map(serde_json::Value::Number)
            .unwrap_or(serde_json::Value::Null),
        Scalar::Text(t) => serde_json::Value::from(t.clone()),
        Scalar::Bool(b) => serde_json::Value::from(*b),
    }
);

fn bundled_campaigns() -> Vec<(PathBuf, toml::Value)> {
    common::toml_files("assets/campaigns")
        .into_iter()
        .map(|p| {
            let v: toml::Value = toml::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
            (p, v)
        })
        .collect()
}

/// Parse and check an edited campaign file; an accepted one expands within the bounds.
fn campaign_case(dir: &Path, original: &Path, tree: &toml::Value) {
    let Ok(text) = toml::to_string(tree) else {
        return; // a tree TOML cannot write (e.g. a table after a value): nothing to test
    };
    // Written beside the original's name, in a temporary folder (scenarios resolve relative to
    // the campaign file; they are not loaded here).
    let path = dir.join(original.file_name().unwrap());
    std::fs::write(&path, &text).unwrap();
    let config = match CampaignConfig::load(&path) {
        Ok(c) => c,
        Err(e) => {
            assert!(e.to_string().contains(&path.display().to_string()), "{e}");
            return;
        }
    };
    match config.check(&path) {
        Ok(methods) => {
            let plan = Campaign::plan(config.clone());
            assert!(plan.cells.len() <= MAX_CELLS);
            assert!(plan.cells.len() * methods.len() * config.seeds <= MAX_JOBS);
            // Labels of one arm's cells are distinct (no cell counted twice).
            let mut labels: Vec<(usize, &str)> = plan
                .cells
                .iter()
                .map(|c| (c.arm, c.label.as_str()))
                .collect();
            labels.sort();
            let n = labels.len();
            labels.dedup();
            assert_eq!(labels.len(), n, "a repeated cell was accepted");
        }
        Err(e) => assert!(e.to_string().contains(&path.display().to_string()), "{e}"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn edited_campaign_files_are_values_or_errors(which in any::<usize>(), edits in edits()) {
        let files = bundled_campaigns();
        let (path, tree) = &files[which % files.len()];
        let mut tree = tree.clone();
        for e in &edits {
            apply(&mut tree, e);
        }
        let tmp = tempfile::tempdir().unwrap();
        campaign_case(tmp.path(), path, &tree);
    }
}

/// The two shards' records of a tiny campaign with a reaching benchmark (computed once).
fn shards() -> &'static (serde_json::Value, serde_json::Value) {
    static SHARDS: std::sync::OnceLock<(serde_json::Value, serde_json::Value)> =
        std::sync::OnceLock::new();
    SHARDS.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("c.toml");
        let text = common::tiny_campaign(
            "records_fuzz",
            "[reaching]\ntasks = 2\nduration = 0.5\ncalibration_runs = 2\n",
        )
        .replace("seeds = 1", "seeds = 2");
        std::fs::write(&path, text).unwrap();
        let campaign = Campaign::load(&path, &[]).unwrap();
        let run = |k| {
            let r =
                run_campaign(&campaign, Shard { index: k, count: 2 }, None, &|_, _| {}).unwrap();
            serde_json::to_value(&r).unwrap()
        };
        (run(1), run(2))
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn edited_records_are_refused_or_merge_within_bounds(first in any::<bool>(), edits in edits()) {
        let (a, b) = shards();
        let (mut edited, other) = if first { (a.clone(), b) } else { (b.clone(), a) };
        for e in &edits {
            apply(&mut edited, e);
        }
        let Ok(records) = serde_json::from_value::<CampaignRecords>(edited) else {
            return Ok(());
        };
        let other: CampaignRecords = serde_json::from_value(other.clone()).unwrap();
        if check_records(&records).is_ok() {
            prop_assert!(records.jobs <= MAX_JOBS + 100_000_000);
        }
        // Merging never panics; when it succeeds the result is whole and consistent.
        if let Ok(m) = merge(&[records, other]) {
            prop_assert!(check_records(&m).is_ok());
            let methods = m.config.methods.as_ref().map_or(aift::scenario::Method::ALL.len(), Vec::len);
            prop_assert_eq!(m.runs.len() + m.reaching.len() / methods, m.jobs);
        }
    }
}

#[test]
fn the_unedited_records_merge() {
    let (a, b) = shards();
    let a: CampaignRecords = serde_json::from_value(a.clone()).unwrap();
    let b: CampaignRecords = serde_json::from_value(b.clone()).unwrap();
    check_records(&a).unwrap();
    let m = merge(&[a, b]).unwrap();
    assert_eq!(m.shard, Shard::WHOLE);
}
