//! The files of a shipped model folder (`models/NAME/`) checked without PyTorch: each file the
//! card lists has the CRC-32C the card records, the actor and both blobs are listed, and the
//! f32 blob holds exactly the actor's weights (it is encoded again from them). The learning
//! stack's `open_model` and the Python package both check a folder with [`verify_model_files`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use shared::blob::{ProblemKind, Quantization};

use crate::actor_file::{read_actor, ActorFileError};

/// The actor's file in a model folder.
pub const ACTOR_FILE: &str = "actor.safetensors";
/// The actor as an ONNX model (the deterministic action), when the folder has it.
pub const ONNX_FILE: &str = "actor.onnx";

/// The files' checksum: CRC-32C, not the blobs' own CRC-32 (ISO-HDLC). A blob ends with the
/// CRC-32 of its payload, so the CRC-32 of the whole file is the same for every blob of one
/// layout and would bind none of them.
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// The file name of a blob: `transfer-f32.blob`, `rendezvous-int8.blob`, ...
pub fn blob_file(kind: ProblemKind, quantization: Quantization) -> String {
    let problem = match kind {
        ProblemKind::Transfer => "transfer",
        ProblemKind::Rendezvous => "rendezvous",
    };
    let q = match quantization {
        Quantization::F32 => "f32",
        Quantization::Int8 => "int8",
    };
    format!("{problem}-{q}.blob")
}

/// Why a model folder's files were refused.
#[derive(Debug, thiserror::Error)]
pub enum ModelFilesError {
    /// A file could not be read.
    #[error("{}: {source}", .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A file's CRC-32C is not the one the card records.
    #[error("{}: CRC-32C {found}, the card says {recorded}: the file is not the one the card describes", .path.display())]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Its CRC-32C (8 hex digits).
        found: String,
        /// The card's.
        recorded: String,
    },
    /// The card does not list a file every model has (the actor, either blob).
    #[error("model folder {}: the card lists no {missing}", .dir.display())]
    Incomplete {
        /// The model folder.
        dir: PathBuf,
        /// The file it does not list.
        missing: String,
    },
    /// The f32 blob does not decode or is not the actor's weights encoded again.
    #[error("{}: the f32 blob does not hold the actor's weights", .path.display())]
    BlobDisagrees {
        /// The f32 blob.
        path: PathBuf,
    },
    /// The actor file is refused (checksum, format, layout).
    #[error(transparent)]
    Actor(#[from] ActorFileError),
}

/// The CRC-32C of a file's bytes, as a card records it (8 hex digits).
pub fn file_checksum(path: &Path) -> Result<String, ModelFilesError> {
    let bytes = std::fs::read(path).map_err(|source| ModelFilesError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(format!("{:08x}", CRC.checksum(&bytes)))
}

/// A model folder's checked files.
#[derive(Debug, Clone)]
pub struct ModelFiles {
    /// The f32 blob's bytes.
    pub f32_blob: Vec<u8>,
    /// The int8 blob's bytes.
    pub int8_blob: Vec<u8>,
}

/// Checks the model folder `dir` of a `kind` controller against its card's `files` (name to
/// CRC-32C): the actor and both blobs are listed, every listed file has its checksum, and the
/// f32 blob is the actor's weights encoded again. Returns the blobs.
pub fn verify_model_files(
    dir: &Path,
    kind: ProblemKind,
    files: &BTreeMap<String, String>,
) -> Result<ModelFiles, ModelFilesError> {
    let f32_name = blob_file(kind, Quantization::F32);
    let int8_name = blob_file(kind, Quantization::Int8);
    for needed in [ACTOR_FILE, &f32_name, &int8_name] {
        if !files.contains_key(needed) {
            return Err(ModelFilesError::Incomplete {
                dir: dir.to_path_buf(),
                missing: needed.to_string(),
            });
        }
    }
    for (name, recorded) in files {
        let path = dir.join(name);
        let found = file_checksum(&path)?;
        if &found != recorded {
            return Err(ModelFilesError::Checksum {
                path,
                found,
                recorded: recorded.clone(),
            });
        }
    }
    let read = |name: &str| {
        let path = dir.join(name);
        std::fs::read(&path).map_err(|source| ModelFilesError::Io { path, source })
    };
    let (f32_blob, int8_blob) = (read(&f32_name)?, read(&int8_name)?);
    let f32_path = dir.join(&f32_name);
    let provenance = shared::blob::decode(&f32_blob)
        .map(|b| b.provenance.to_string())
        .map_err(|_| ModelFilesError::BlobDisagrees { path: f32_path.clone() })?;
    let rebuilt = read_actor(&dir.join(ACTOR_FILE), kind)?.f32_blob(&provenance).ok();
    if rebuilt.as_deref() != Some(f32_blob.as_slice()) {
        return Err(ModelFilesError::BlobDisagrees { path: f32_path });
    }
    Ok(ModelFiles { f32_blob, int8_blob })
}
