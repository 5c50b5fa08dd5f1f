//! Files that are never half-written: atomic replace (temp file in the same folder, fsync,
//! rename), a checksummed container for record sets, the lock that keeps a run folder to one
//! process, and the check that an output goes into a folder that exists.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically: readers see the old file or the new one, never a part.
pub fn atomic_write(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "path has no file name"))?;
    let tmp = dir.join(temporary_name(&name.to_string_lossy()));
    let written = File::create(&tmp).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    // A failed write (a full disk) or rename leaves no part behind.
    written.and_then(|()| fs::rename(&tmp, path)).inspect_err(|_| {
        let _ = fs::remove_file(&tmp);
    })
}

/// The temporary file [`atomic_write`] writes `name` through: `.NAME.PID.tmp`.
fn temporary_name(name: &str) -> String {
    format!(".{name}.{}.tmp", std::process::id())
}

/// Is `name` one of [`atomic_write`]'s temporary files (of any process)?
fn is_temporary_name(name: &str) -> bool {
    let Some(stem) = name.strip_prefix('.').and_then(|n| n.strip_suffix(".tmp")) else {
        return false;
    };
    stem.rsplit_once('.')
        .is_some_and(|(file, pid)| !file.is_empty() && !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()))
}

/// Removes the temporary files a process that stopped mid-write left in `dir` and its
/// subfolders (a kill, a power cut), leaving any subfolder that is a run folder of its own (it
/// has a lock file) to its holder. Called by the holder of `dir`, so no writer is mid-write.
fn remove_stale_temporaries(dir: &Path) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        if kind.is_dir() {
            if !path.join(LOCK_FILE).exists() {
                remove_stale_temporaries(&path);
            }
        } else if kind.is_file() && is_temporary_name(&entry.file_name().to_string_lossy()) {
            let _ = fs::remove_file(&path);
        }
    }
}

/// An output path whose parent folder is not there.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {} is not an existing folder; create it first", .path.display(), .folder.display())]
pub struct MissingFolder {
    /// The path refused.
    pub path: PathBuf,
    /// Its parent folder, which does not exist.
    pub folder: PathBuf,
}

/// Refuses `path` (a file to write or a folder to create) unless its parent folder exists, so a
/// mistyped output path fails instead of growing a tree of folders wherever it points. A bare
/// name (parent: the working folder) is accepted.
pub fn require_parent_folder(path: &Path) -> Result<(), MissingFolder> {
    match path.parent() {
        Some(folder) if !folder.as_os_str().is_empty() && !folder.is_dir() => Err(MissingFolder {
            path: path.to_path_buf(),
            folder: folder.to_path_buf(),
        }),
        _ => Ok(()),
    }
}

/// Why a container file was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ContainerError {
    /// Shorter than a header and checksum (10 bytes).
    #[error("file is truncated")]
    Truncated,
    /// The first 4 bytes are not the expected magic.
    #[error("not a file of this kind (bad magic)")]
    BadMagic,
    /// The file's format version (given) is not the one read.
    #[error("unsupported format version {0}")]
    UnsupportedVersion(u16),
    /// The payload's CRC-32 does not match the stored one.
    #[error("checksum mismatch: the file is corrupt")]
    CrcMismatch,
    /// The payload does not (de)serialize with postcard, or has trailing bytes.
    #[error("payload does not decode: {0}")]
    Decode(String),
}

const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// The CRC-32 of `bytes`, as the containers carry it: what ties a file to another it answers.
pub fn checksum(bytes: &[u8]) -> u32 {
    CRC.checksum(bytes)
}

/// magic (4) + version (u16 LE) + postcard payload + CRC-32 of the payload (u32 LE).
pub fn encode_container<T: serde::Serialize>(
    magic: [u8; 4],
    version: u16,
    value: &T,
) -> Result<Vec<u8>, ContainerError> {
    let payload = postcard::to_stdvec(value).map_err(|e| ContainerError::Decode(e.to_string()))?;
    let mut out = Vec::with_capacity(payload.len() + 10);
    out.extend_from_slice(&magic);
    out.extend_from_slice(&version.to_le_bytes());
    out.extend_from_slice(&payload);
    out.extend_from_slice(&CRC.checksum(&payload).to_le_bytes());
    Ok(out)
}

/// Inverse of [`encode_container`]; refuses anything that is not exactly such a file.
pub fn decode_container<T: serde::de::DeserializeOwned>(
    magic: [u8; 4],
    version: u16,
    bytes: &[u8],
) -> Result<T, ContainerError> {
    if bytes.len() < 10 {
        return Err(ContainerError::Truncated);
    }
    let (head, rest) = bytes.split_at(6);
    if head[..4] != magic {
        return Err(ContainerError::BadMagic);
    }
    let found = u16::from_le_bytes([head[4], head[5]]);
    if found != version {
        return Err(ContainerError::UnsupportedVersion(found));
    }
    let (payload, crc) = rest.split_at(rest.len() - 4);
    if CRC.checksum(payload).to_le_bytes() != crc {
        return Err(ContainerError::CrcMismatch);
    }
    let (value, unused) = postcard::take_from_bytes(payload).map_err(|e| ContainerError::Decode(e.to_string()))?;
    if !unused.is_empty() {
        return Err(ContainerError::Decode(format!("{} trailing bytes", unused.len())));
    }
    Ok(value)
}

/// The lock file of a run folder.
pub const LOCK_FILE: &str = ".lock";

/// Why a run folder could not be held.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    #[error("{} is in use by another process ({holder}); wait for it or use another folder", .dir.display())]
    /// Another process (or another hold in this one) holds the folder.
    Held {
        /// The run folder.
        dir: PathBuf,
        /// What the lock file says about the holder (`pid N`), or "unknown process".
        holder: String,
    },
    #[error("cannot lock {}: {source}", .dir.display())]
    /// Creating the folder, or opening or locking its lock file, failed.
    Io {
        /// The run folder.
        dir: PathBuf,
        /// The underlying error.
        source: io::Error,
    },
}

/// An exclusive hold on a run folder for the life of the value: an OS advisory lock on
/// `DIR/.lock` (flock on Unix), released when the value is dropped or the process dies, so a
/// killed run never leaves a stale lock. The file itself stays; it names the last holder.
#[derive(Debug)]
pub struct RunLock {
    file: File,
    dir: PathBuf,
}

impl RunLock {
    /// Holds `dir` (created if missing), or refuses if another holder has it. Two holds of one
    /// folder conflict even inside one process. The new holder removes the temporary files of
    /// writes that a stopped process left unfinished in the folder.
    pub fn acquire(dir: &Path) -> Result<Self, LockError> {
        let io_err = |source| LockError::Io {
            dir: dir.to_path_buf(),
            source,
        };
        fs::create_dir_all(dir).map_err(io_err)?;
        let path = dir.join(LOCK_FILE);
        let mut file = fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io_err)?;
        match file.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                let holder = fs::read_to_string(&path).unwrap_or_default();
                let holder = match holder.trim() {
                    "" => "unknown process".to_string(),
                    h => h.to_string(),
                };
                return Err(LockError::Held {
                    dir: dir.to_path_buf(),
                    holder,
                });
            }
            Err(fs::TryLockError::Error(e)) => return Err(io_err(e)),
        }
        // Who holds it, for the refusal of the next one (best effort: the lock is what counts).
        let _ = file.set_len(0).and_then(|()| {
            use std::io::Seek;
            file.seek(io::SeekFrom::Start(0))?;
            write!(file, "pid {}", std::process::id())
        });
        remove_stale_temporaries(dir);
        Ok(Self {
            file,
            dir: dir.to_path_buf(),
        })
    }

    /// The folder held.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for RunLock {
    fn drop(&mut self) {
        let _ = self.file.unlock();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_folder_is_held_by_one_holder_at_a_time() {
        let dir = std::env::temp_dir().join(format!("lowthrust-lock-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let first = RunLock::acquire(&dir.join("run")).unwrap();
        match RunLock::acquire(&dir.join("run")) {
            Err(LockError::Held { holder, .. }) => assert_eq!(holder, format!("pid {}", std::process::id())),
            other => panic!("second hold not refused: {other:?}"),
        }
        // Another folder is free; the first one is free again once released.
        let other = RunLock::acquire(&dir.join("other")).unwrap();
        drop(first);
        let again = RunLock::acquire(&dir.join("run")).unwrap();
        assert_eq!(again.dir(), dir.join("run"));
        drop((other, again));
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_new_holder_removes_the_temporaries_a_stopped_writer_left() {
        let dir = std::env::temp_dir().join(format!("lowthrust-stale-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        let run = dir.join("run");
        for folder in ["records", "stage/deeper", "held"] {
            fs::create_dir_all(run.join(folder)).unwrap();
        }
        // What a killed writer leaves: its temporaries, beside files that only look alike.
        let stale = [
            ".000068.rec.4242.tmp",
            "records/.000068.rec.4242.tmp",
            "stage/deeper/.dataset.ltds.7.tmp",
        ];
        let kept = [
            "000068.rec",
            "notes.tmp",
            ".hidden",
            "records/.x.tmp",
            "records/.a.12b.tmp",
            "held/.000001.rec.99.tmp",
        ];
        for name in stale.iter().chain(&kept) {
            fs::write(run.join(name), "x").unwrap();
        }
        // A subfolder with its own lock is another run folder: its holder cleans it.
        fs::write(run.join("held").join(LOCK_FILE), "").unwrap();
        let hold = RunLock::acquire(&run).unwrap();
        for name in stale {
            assert!(!run.join(name).exists(), "{name} left behind");
        }
        for name in kept {
            assert!(run.join(name).exists(), "{name} removed");
        }
        drop(hold);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_output_needs_an_existing_parent_folder() {
        let dir = std::env::temp_dir().join(format!("lowthrust-parent-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        assert_eq!(require_parent_folder(&dir.join("out.svg")), Ok(()));
        assert_eq!(require_parent_folder(&dir.join("run/")), Ok(()));
        assert_eq!(require_parent_folder(Path::new("bare-name.svg")), Ok(()));
        let deep = dir.join("missing").join("run");
        assert_eq!(
            require_parent_folder(&deep),
            Err(MissingFolder {
                path: deep.clone(),
                folder: dir.join("missing"),
            })
        );
        // A file where the folder should be is no folder either.
        fs::write(dir.join("file"), "x").unwrap();
        assert!(require_parent_folder(&dir.join("file").join("out.svg")).is_err());
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 1, "the check creates nothing");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn container_round_trips_and_refuses_every_corruption() {
        let value: Vec<(u32, f64, String)> = (0..50).map(|i| (i, f64::from(i) * 0.5, format!("r{i}"))).collect();
        let bytes = encode_container(*b"TEST", 3, &value).unwrap();
        assert_eq!(
            decode_container::<Vec<(u32, f64, String)>>(*b"TEST", 3, &bytes).unwrap(),
            value
        );
        for len in 0..bytes.len() {
            assert!(decode_container::<Vec<(u32, f64, String)>>(*b"TEST", 3, &bytes[..len]).is_err());
        }
        for i in 0..bytes.len() {
            for bit in 0..8 {
                let mut b = bytes.clone();
                b[i] ^= 1 << bit;
                assert!(
                    decode_container::<Vec<(u32, f64, String)>>(*b"TEST", 3, &b).is_err(),
                    "byte {i} bit {bit}"
                );
            }
        }
        assert_eq!(
            decode_container::<Vec<(u32, f64, String)>>(*b"TEST", 4, &bytes),
            Err(ContainerError::UnsupportedVersion(3))
        );
        assert_eq!(
            decode_container::<Vec<(u32, f64, String)>>(*b"XEST", 3, &bytes),
            Err(ContainerError::BadMagic)
        );
    }

    #[test]
    fn atomic_write_replaces_whole_files_and_leaves_no_temporaries() {
        let dir = std::env::temp_dir().join(format!("lowthrust-io-test-{}", std::process::id()));
        let path = dir.join("a.bin");
        atomic_write(&path, b"first").unwrap();
        atomic_write(&path, b"second, longer").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"second, longer");
        let names: Vec<_> = fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.bin")]);
        fs::remove_dir_all(&dir).unwrap();
    }
}
