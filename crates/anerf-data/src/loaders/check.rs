//! One reading code path for two uses: [`crate::loaders::load`] stops at the first problem, while
//! [`crate::info::inspect`] records every problem and carries on with what it could read.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::error::DataError;

/// One thing wrong with a dataset.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Problem {
    /// Fatal problems stop loading; the others are worth knowing (e.g. a fallback was used).
    pub fatal: bool,
    pub path: PathBuf,
    pub message: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let level = if self.fatal { "error" } else { "warning" };
        write!(f, "{level}: {}", self.message)
    }
}

/// At most this many problems are listed one by one; the rest are counted.
pub const MAX_LISTED: usize = 200;

/// Fails fast (loading) or collects (inspection).
pub(crate) struct Checker {
    collect: bool,
    whole_files: bool,
    pub problems: Vec<Problem>,
    pub notes: Vec<String>,
    unlisted: usize,
}

impl Checker {
    pub fn fail_fast() -> Self {
        Self {
            collect: false,
            whole_files: false,
            problems: Vec::new(),
            notes: Vec::new(),
            unlisted: 0,
        }
    }

    /// Collects every problem, and reads every file whole (images and masks checked for truncation,
    /// posed vertices for their values), where loading reads headers only and leaves the rest to `prepare`.
    pub fn collecting() -> Self {
        Self {
            collect: true,
            whole_files: true,
            ..Self::fail_fast()
        }
    }

    /// Whether files the loader only names are read in full to check them.
    pub fn whole_files(&self) -> bool {
        self.whole_files
    }

    /// Passes a success through; a failure is returned (fail-fast) or recorded as `Ok(None)` (collecting).
    pub fn check<T>(&mut self, r: Result<T, DataError>) -> Result<Option<T>, DataError> {
        match r {
            Ok(v) => Ok(Some(v)),
            Err(e) if self.collect => {
                self.record(Problem {
                    fatal: true,
                    path: e.path().to_path_buf(),
                    message: e.to_string(),
                });
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    /// A non-fatal remark, kept in `Subject::notes` and listed by inspection.
    pub fn note(&mut self, path: &Path, message: String) {
        self.notes.push(message.clone());
        self.record(Problem {
            fatal: false,
            path: path.to_path_buf(),
            message,
        });
    }

    fn record(&mut self, p: Problem) {
        if self.problems.len() < MAX_LISTED {
            self.problems.push(p);
        } else {
            self.unlisted += 1;
        }
    }

    /// The problems, with a closing line counting those not listed.
    pub fn finish(mut self) -> (Vec<Problem>, Vec<String>) {
        if self.unlisted > 0 {
            let fatal = self.problems.iter().any(|p| p.fatal);
            self.problems.push(Problem {
                fatal,
                path: PathBuf::new(),
                message: format!("… and {} more problems not listed", self.unlisted),
            });
        }
        (self.problems, self.notes)
    }
}
