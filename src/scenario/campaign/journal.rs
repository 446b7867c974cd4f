//! A campaign's journal: every job written down as it finishes, so that a campaign killed part
//! way (kill -9, SIGTERM, a node lost in an array) is resumed by running it again, redoing only
//! the jobs it had not finished (docs/campaigns.md, "Resuming").
//!
//! The journal is a JSON Lines file: a header naming the campaign (fingerprint, configuration
//! digest, shard, aift version and build), then one line per finished job with its records in
//! full precision and the seconds it took. Lines are appended and flushed as jobs finish and
//! synced to disk at most once a second, so a killed process loses at most the job it was
//! writing and a lost machine at most the last second. A torn last line is dropped; a header
//! that does not match the campaign as run now (another configuration, overrides, shard,
//! version or build) starts the journal afresh. The version alone does not tell builds apart (it
//! stays the same between commits): the header carries the build's source digest
//! ([`crate::fsio::SOURCE_DIGEST`]), so that a campaign rerun after a rebuild never mixes the
//! jobs of two builds. A job's records are the same whether computed now or read back (serde's
//! shortest round-trip floats), so a resumed campaign writes the same bytes as an uninterrupted
//! one.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{Campaign, CampaignRun, ReachingRun, Shard};
use crate::fsio::FsError;

/// Version of the journal's layout.
pub const JOURNAL_FORMAT: u32 = 1;
/// Most bytes of a journal read back (as a campaign's records).
pub const MAX_JOURNAL_BYTES: u64 = crate::fsio::MAX_CALIBRATION_BYTES;

/// The first line: which campaign, shard and build wrote the journal.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    aift_campaign_journal: u32,
    aift_version: String,
    /// [`crate::fsio::SOURCE_DIGEST`] of the build that wrote it.
    build: String,
    campaign: String,
    fingerprint: String,
    config_digest: String,
    shard: Shard,
    jobs: usize,
}

/// One finished job: a cell job's run, or a reaching task's runs (one per method).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    job: usize,
    seconds: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    run: Option<CampaignRun>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    reaching: Option<Vec<ReachingRun>>,
}

/// What to do with a journal found in place.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JournalMode {
    /// Resume a matching journal; replace one of another run.
    Resume,
    /// Resume a matching journal, or refuse.
    Require,
    /// Replace any journal.
    Fresh,
}

/// How a journal was opened.
#[derive(Clone, Debug, PartialEq)]
pub enum JournalStart {
    /// No journal was there: a new one.
    New,
    /// A journal of this campaign and shard: `jobs` of its jobs are done, `seconds` of work.
    Resumed { jobs: usize, seconds: f64 },
    /// A journal of another campaign, configuration, shard or version (the reason), replaced.
    Replaced(String),
}

struct Writer {
    file: File,
    last_sync: Instant,
}

/// The journal of one campaign (or shard) run.
pub struct Journal {
    path: PathBuf,
    writer: Mutex<Writer>,
    runs: BTreeMap<usize, CampaignRun>,
    reaching: BTreeMap<usize, Vec<ReachingRun>>,
}

impl Journal {
    /// The journal of a campaign written to the folder `out`: `.NAME.aift-journal` beside it.
    pub fn path_for(out: &Path) -> PathBuf {
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let parent = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        parent.join(format!(".{name}.aift-journal"))
    }

    /// Opens the journal at `path` for `campaign` and `shard`: the jobs it holds when its header
    /// matches (a torn last line dropped), else a new journal in its place. `Fresh` replaces any
    /// journal there; `Require` refuses (leaving the file as it is) unless there is a matching
    /// one.
    pub fn open(
        path: &Path,
        campaign: &Campaign,
        shard: Shard,
        mode: JournalMode,
    ) -> Result<(Self, JournalStart), FsError> {
        let fresh = mode == JournalMode::Fresh;
        let header = Header {
            aift_campaign_journal: JOURNAL_FORMAT,
            aift_version: env!("CARGO_PKG_VERSION").into(),
            build: crate::fsio::SOURCE_DIGEST.into(),
            campaign: campaign.config.name.clone(),
            fingerprint: campaign.fingerprint.clone(),
            config_digest: super::config_digest(&campaign.config),
            shard,
            jobs: campaign.jobs().len() + campaign.reaching_tasks().len(),
        };
        let write_err = |source| FsError::Write {
            path: path.to_path_buf(),
            source,
        };
        let (mut runs, mut reaching) = (BTreeMap::new(), BTreeMap::new());
        let mut start = JournalStart::New;
        let mut keep = 0u64;
        if !fresh && path.exists() {
            let text = crate::fsio::read_bounded(path, MAX_JOURNAL_BYTES)?;
            match read_entries(&text, &header, campaign, shard) {
                Ok((end, entries)) => {
                    keep = end as u64;
                    let mut seconds = 0.0;
                    for e in entries {
                        seconds += e.seconds;
                        if let Some(r) = e.run {
                            runs.insert(e.job, r);
                        } else if let Some(r) = e.reaching {
                            reaching.insert(e.job, r);
                        }
                    }
                    start = JournalStart::Resumed {
                        jobs: runs.len() + reaching.len(),
                        seconds,
                    };
                }
                Err(reason) => start = JournalStart::Replaced(reason),
            }
        } else if fresh && path.exists() {
            start = JournalStart::Replaced("discarded (fresh start asked for)".into());
        }
        if mode == JournalMode::Require {
            let why = match &start {
                JournalStart::Resumed { .. } => None,
                JournalStart::New => Some("there is no journal of an interrupted run".to_string()),
                JournalStart::Replaced(reason) => Some(format!("its journal is {reason}")),
            };
            if let Some(why) = why {
                return Err(FsError::BadOutput {
                    path: path.to_path_buf(),
                    message: format!("nothing to resume: {why}"),
                });
            }
        }
        let mut file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(path)
            .map_err(write_err)?;
        if keep == 0 {
            file.set_len(0).map_err(write_err)?;
            let mut line = serde_json::to_string(&header).expect("a header serialises");
            line.push('\n');
            file.write_all(line.as_bytes()).map_err(write_err)?;
        } else {
            // Drop a torn last line before appending after it.
            file.set_len(keep).map_err(write_err)?;
        }
        use std::io::Seek;
        file.seek(std::io::SeekFrom::End(0)).map_err(write_err)?;
        file.sync_data().map_err(write_err)?;
        Ok((
            Self {
                path: path.to_path_buf(),
                writer: Mutex::new(Writer {
                    file,
                    last_sync: Instant::now(),
                }),
                runs,
                reaching,
            },
            start,
        ))
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A finished cell job's run, if the journal holds it.
    pub fn run(&self, job: usize) -> Option<&CampaignRun> {
        self.runs.get(&job)
    }

    /// A finished reaching job's runs, if the journal holds them.
    pub fn reaching(&self, job: usize) -> Option<&Vec<ReachingRun>> {
        self.reaching.get(&job)
    }

    /// Writes down a finished cell job.
    pub fn record_run(&self, run: &CampaignRun, seconds: f64) -> Result<(), FsError> {
        self.append(&Entry {
            job: run.job,
            seconds,
            run: Some(run.clone()),
            reaching: None,
        })
    }

    /// Writes down a finished reaching job.
    pub fn record_reaching(
        &self,
        job: usize,
        runs: &[ReachingRun],
        seconds: f64,
    ) -> Result<(), FsError> {
        self.append(&Entry {
            job,
            seconds,
            run: None,
            reaching: Some(runs.to_vec()),
        })
    }

    fn append(&self, entry: &Entry) -> Result<(), FsError> {
        let mut line = serde_json::to_string(entry).expect("an entry serialises");
        line.push('\n');
        let mut w = self.writer.lock().unwrap_or_else(|e| e.into_inner());
        let err = |source| FsError::Write {
            path: self.path.clone(),
            source,
        };
        w.file.write_all(line.as_bytes()).map_err(err)?;
        if w.last_sync.elapsed().as_secs_f64() >= 1.0 {
            w.file.sync_data().map_err(err)?;
            w.last_sync = Instant::now();
        }
        Ok(())
    }

    /// Removes the journal (after the campaign's folder is in place).
    pub fn remove(self) -> Result<(), FsError> {
        drop(self.writer);
        std::fs::remove_file(&self.path).map_err(|source| FsError::Write {
            path: self.path.clone(),
            source,
        })
    }
}

/// The entries of a journal whose header is `header`, and the byte length of its complete,
/// readable lines; an error says why the journal cannot be used.
fn read_entries(
    bytes: &[u8],
    header: &Header,
    campaign: &Campaign,
    shard: Shard,
) -> Result<(usize, Vec<Entry>), String> {
    let mut lines = bytes.split_inclusive(|b| *b == b'\n');
    let first = lines.next().ok_or("it is empty")?;
    let found: Header = std::str::from_utf8(first)
        .ok()
        .and_then(|t| serde_json::from_str(t.trim_end()).ok())
        .ok_or("its header is unreadable")?;
    if found != *header {
        return Err(if found.aift_version != header.aift_version {
            format!("written by aift {}", found.aift_version)
        } else if found.build != header.build {
            format!(
                "written by another build of aift (source digest {}; this one {})",
                found.build, header.build
            )
        } else if found.shard != header.shard {
            format!("of shard {}/{}", found.shard.index, found.shard.count)
        } else {
            "of another configuration (file, options or --set)".into()
        });
    }
    let cell_jobs = campaign.jobs().len();
    let all = cell_jobs + campaign.reaching_tasks().len();
    let mut end = first.len();
    let mut entries = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for line in lines {
        // A line without its newline was torn by a kill: it and anything after are dropped.
        if !line.ends_with(b"\n") {
            break;
        }
        let Some(entry) = std::str::from_utf8(line)
            .ok()
            .and_then(|t| serde_json::from_str::<Entry>(t.trim_end()).ok())
        else {
            break;
        };
        let j = entry.job;
        let fits = j < all
            && shard.contains(j)
            && seen.insert(j)
            && match (&entry.run, &entry.reaching) {
                (Some(r), None) => {
                    j < cell_jobs
                        && r.job == j
                        && campaign.job(j).is_some_and(|(c, m, s)| {
                            r.cell == c && r.method == *m && s < usize::MAX
                        })
                }
                (None, Some(rs)) => j >= cell_jobs && rs.iter().all(|r| r.job == j),
                _ => false,
            };
        if !fits {
            return Err(format!(
                "its line for job {j} does not belong to this campaign"
            ));
        }
        end += line.len();
        entries.push(entry);
    }
    Ok((end, entries))
}
