//! Output folder locks: OS file locks (`flock`), so the kernel releases them when the
//! holder ends, however it ends (kill -9 included).
//!
//! - A run of the whole job, `merge`, `postprocess` and finishing take the folder's lock
//!   `DIR/.synosis.lock` exclusively: no other writer at the same time.
//! - A run of shard i/n (n > 1) takes the folder's lock shared and the shard's lock
//!   `DIR/manifests/.shard-i-of-n.lock` exclusively: shards of one job may run at the same
//!   time in one folder (they write disjoint images and their own manifests), but two
//!   processes of the same shard may not, nor a shard beside a whole-job run or a merge.
//!
//! Each lock file holds the pid of its last holder, so a refusal names the process.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::error::{DatasetError, Result};

/// The name of the folder's lock file.
pub const DIR_LOCK: &str = ".synosis.lock";

/// Held locks; dropping the value (or the process ending) releases them.
#[derive(Debug)]
pub struct DirLock {
    _files: Vec<File>,
    /// Lock files this lock created (a failed run that undoes its work removes them).
    pub created: Vec<PathBuf>,
}

/// Which lock a writer needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// The only writer of the folder.
    Exclusive,
    /// One shard (index, count) beside other shards of the same layout or others.
    Shard(usize, usize),
}

fn shard_lock_path(dir: &Path, index: usize, count: usize) -> PathBuf {
    dir.join("manifests")
        .join(format!(".shard-{index}-of-{count}.lock"))
}

fn open(path: &Path, created: &mut Vec<PathBuf>) -> Result<File> {
    let existed = path.exists();
    let f = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .map_err(|e| DatasetError::io(path, e))?;
    if !existed {
        created.push(path.to_path_buf());
    }
    Ok(f)
}

fn write_pid(f: &mut File, path: &Path) -> Result<()> {
    (|| {
        f.set_len(0)?;
        f.seek(SeekFrom::Start(0))?;
        writeln!(f, "{}", std::process::id())?;
        f.sync_all()
    })()
    .map_err(|e| DatasetError::io(path, e))
}

fn read_pid(path: &Path) -> Option<String> {
    let mut s = String::new();
    File::open(path).ok()?.read_to_string(&mut s).ok()?;
    let s = s.trim();
    (!s.is_empty()).then(|| s.to_string())
}

/// Pids of the shard locks of `dir` that some process holds now.
fn shard_holders(dir: &Path) -> Vec<String> {
    let mut pids = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir.join("manifests")) else {
        return pids;
    };
    let mut paths: Vec<PathBuf> = rd
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "lock"))
        .collect();
    paths.sort();
    for p in paths {
        let Ok(f) = File::open(&p) else { continue };
        if let Err(TryLockError::WouldBlock) = f.try_lock_shared() {
            pids.extend(read_pid(&p));
        }
    }
    pids
}

fn busy(dir: &Path, pids: Vec<String>) -> DatasetError {
    DatasetError::Locked {
        dir: dir.to_path_buf(),
        holder: if pids.is_empty() {
            "pid unknown".into()
        } else {
            format!("pid {}", pids.join(", pid "))
        },
    }
}

/// Takes the lock `access` needs on `dir` (which must exist, with `manifests/` for a
/// shard), or fails at once with [`DatasetError::Locked`] naming the holder's pid.
pub fn lock(dir: &Path, access: Access) -> Result<DirLock> {
    let mut created = Vec::new();
    let path = dir.join(DIR_LOCK);
    let mut f = open(&path, &mut created)?;
    match access {
        Access::Exclusive => {
            match f.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    let mut pids = shard_holders(dir);
                    if pids.is_empty() {
                        pids.extend(read_pid(&path));
                    }
                    return Err(busy(dir, pids));
                }
                Err(TryLockError::Error(e)) => return Err(DatasetError::io(&path, e)),
            }
            write_pid(&mut f, &path)?;
            Ok(DirLock {
                _files: vec![f],
                created,
            })
        }
        Access::Shard(index, count) => {
            match f.try_lock_shared() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    return Err(busy(dir, read_pid(&path).into_iter().collect()));
                }
                Err(TryLockError::Error(e)) => return Err(DatasetError::io(&path, e)),
            }
            let spath = shard_lock_path(dir, index, count);
            let mut s = open(&spath, &mut created)?;
            match s.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    return Err(busy(dir, read_pid(&spath).into_iter().collect()));
                }
                Err(TryLockError::Error(e)) => return Err(DatasetError::io(&spath, e)),
            }
            write_pid(&mut s, &spath)?;
            Ok(DirLock {
                _files: vec![f, s],
                created,
            })
        }
    }
}
