//! The files of a shipped model folder (`models/NAME/`) checked without PyTorch: each file the
//! card lists has the CRC-32C the card records, the actor and both blobs are listed, and the
//! f32 blob holds exactly the actor's weights (it is encoded again from them). The learning
//! stack's `open_model` and the Python package both check a folder with [`verify_model_files`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use shared::blob::{FeatureLayout, ProblemKind, Quantization};

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
    /// card.json is not a JSON object.
    #[error("{}: the card does not parse: {reason}", .path.display())]
    CardUnreadable {
        /// The card.json file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// card.json's content is not what its writer sealed: edited by hand after it was written.
    #[error(
        "{}: the card was changed after it was written (its content's CRC-32C is {found}, its seal {recorded}); \
         a card is written by `ground model ship` or `ground model export --model`, never by hand",
        .path.display()
    )]
    CardEdited {
        /// The card.json file.
        path: PathBuf,
        /// The CRC-32C of its content.
        found: String,
        /// The seal it carries.
        recorded: String,
    },
}

/// The key of card.json that holds the card's seal: the CRC-32C of the rest of its content.
pub const CARD_SEAL: &str = "seal";

/// The seal of a card: the CRC-32C (8 hex digits) of its content, every key but the seal, as
/// canonical JSON (object keys sorted, no spaces). A change of any value, key or element changes
/// it; the layout of the file (indentation, key order) does not.
pub fn card_seal(card: &serde_json::Value) -> String {
    fn canonical(value: &serde_json::Value, top: bool, out: &mut String) {
        match value {
            serde_json::Value::Object(map) => {
                let mut keys: Vec<&String> = map.keys().filter(|k| !(top && *k == CARD_SEAL)).collect();
                keys.sort();
                out.push('{');
                for (i, key) in keys.into_iter().enumerate() {
                    if i > 0 {
                        out.push(',');
                    }
                    out.push_str(&serde_json::Value::String(key.clone()).to_string());
                    out.push(':');
                    canonical(&map[key], false, out);
                }
                out.push('}');
            }
            serde_json::Value::Array(items) => {
                out.push('[');
                for (i, item) in items.iter().enumerate() {
                    if i > 0 {
                        out.push(',');
                    }
                    canonical(item, false, out);
                }
                out.push(']');
            }
            scalar => out.push_str(&scalar.to_string()),
        }
    }
    let mut text = String::new();
    canonical(card, true, &mut text);
    format!("{:08x}", CRC.checksum(text.as_bytes()))
}

/// Reads card.json's text as its writer sealed it: refused unless it parses as an object whose
/// seal is the CRC-32C of its content ([`card_seal`]).
pub fn read_sealed_card(path: &Path, text: &str) -> Result<serde_json::Value, ModelFilesError> {
    let card: serde_json::Value = serde_json::from_str(text).map_err(|e| ModelFilesError::CardUnreadable {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    if !card.is_object() {
        return Err(ModelFilesError::CardUnreadable {
            path: path.to_path_buf(),
            reason: "not a JSON object".into(),
        });
    }
    let recorded = card
        .get(CARD_SEAL)
        .and_then(|s| s.as_str())
        .unwrap_or("none")
        .to_string();
    let found = card_seal(&card);
    if found != recorded {
        return Err(ModelFilesError::CardEdited {
            path: path.to_path_buf(),
            found,
            recorded,
        });
    }
    Ok(card)
}

/// The seal of the card whose JSON text (its seal empty or absent) is `unsealed`: computed on
/// the text as a reader parses it, so the reader of the sealed file computes the same.
pub fn seal_of_text(unsealed: &str) -> Result<String, serde_json::Error> {
    Ok(card_seal(&serde_json::from_str(unsealed)?))
}

/// The text of a card sealed: `card` (an object) written as pretty JSON with its seal.
pub fn sealed_card_text(card: &serde_json::Value) -> Result<String, serde_json::Error> {
    let seal = seal_of_text(&serde_json::to_string_pretty(card)?)?;
    let mut card = card.clone();
    if let Some(map) = card.as_object_mut() {
        map.insert(CARD_SEAL.into(), serde_json::Value::String(seal));
    }
    serde_json::to_string_pretty(&card)
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

/// Checks that every file the card lists (`files`: name to CRC-32C) in the folder `dir` has its
/// checksum.
pub fn verify_checksums(dir: &Path, files: &BTreeMap<String, String>) -> Result<(), ModelFilesError> {
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
    Ok(())
}

/// Checks the model folder `dir` of a controller of input encoding `features` (its problem,
/// planar or three-dimensional) against its card's `files` (name to CRC-32C): the actor and
/// both blobs are listed, every listed file has its checksum, and the f32 blob is the actor's
/// weights encoded again as a network of `features` (a blob of another problem or dimension
/// disagrees). Returns the blobs.
pub fn verify_model_files(
    dir: &Path,
    features: FeatureLayout,
    files: &BTreeMap<String, String>,
) -> Result<ModelFiles, ModelFilesError> {
    let kind = features.problem();
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
    verify_checksums(dir, files)?;
    let read = |name: &str| {
        let path = dir.join(name);
        std::fs::read(&path).map_err(|source| ModelFilesError::Io { path, source })
    };
    let (f32_blob, int8_blob) = (read(&f32_name)?, read(&int8_name)?);
    let f32_path = dir.join(&f32_name);
    let same = {
        let shipped =
            shared::blob::decode(&f32_blob).map_err(|_| ModelFilesError::BlobDisagrees { path: f32_path.clone() })?;
        // Encoded again from the actor, as a network of the card's layout, with the blob's own
        // provenance and mission, it must be the same network (compared decoded, so that the
        // padding the encoder chooses does not matter).
        let rebuilt = read_actor(&dir.join(ACTOR_FILE), features)?
            .f32_blob_for(shipped.provenance, shipped.mission)
            .ok();
        rebuilt
            .as_deref()
            .and_then(|bytes| shared::blob::decode(bytes).ok())
            .is_some_and(|network| network == shipped)
    };
    if !same {
        return Err(ModelFilesError::BlobDisagrees { path: f32_path });
    }
    Ok(ModelFiles { f32_blob, int8_blob })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn card() -> serde_json::Value {
        serde_json::json!({
            "format": 3,
            "config": "[env.spacecraft]\nmax_thrust_n = 1.33\n",
            "monte_carlo": { "within": [[0.01, 0.969], [0.001, 0.044]], "dr_p50": 0.0027 },
            "files": { "actor.safetensors": "0a1b2c3d" },
            "notes": ["first", "second"],
            "lookahead": null,
            "tiny": 1.2345678901234567e-300,
        })
    }

    /// A shipped planar folder checks as its own layout, and disagrees as the three-dimensional
    /// layout of its problem (its actor is not that network) or as the other problem (its blobs
    /// are not that problem's).
    #[test]
    fn a_folder_checks_only_as_the_layout_of_its_card() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/transfer-circular");
        let text = std::fs::read_to_string(dir.join("card.json")).unwrap();
        let card = read_sealed_card(&dir.join("card.json"), &text).unwrap();
        let files: BTreeMap<String, String> = serde_json::from_value(card["files"].clone()).unwrap();
        assert!(verify_model_files(&dir, FeatureLayout::TransferPolar10, &files).is_ok());
        assert!(matches!(
            verify_model_files(&dir, FeatureLayout::TransferSpatial15, &files),
            Err(ModelFilesError::BlobDisagrees { .. })
        ));
        assert!(matches!(
            verify_model_files(&dir, FeatureLayout::RendezvousPolar22, &files),
            Err(ModelFilesError::Incomplete { .. })
        ));
    }

    #[test]
    fn a_sealed_card_reads_back_and_any_edit_of_its_content_is_refused() {
        let path = Path::new("card.json");
        let text = sealed_card_text(&card()).unwrap();
        let read = read_sealed_card(path, &text).unwrap();
        assert_eq!(read.get(CARD_SEAL).and_then(|s| s.as_str()).map(str::len), Some(8));
        // The layout is not content: compact, or keys in another order, the card still reads.
        let compact = serde_json::to_string(&read).unwrap();
        read_sealed_card(path, &compact).unwrap();
        let edits: [(&str, &str); 7] = [
            ("max_thrust_n = 1.33", "max_thrust_n = 2.5"),
            ("0.969", "0.979"),
            ("0.0027", "0.0026"),
            ("0a1b2c3d", "0a1b2c3e"),
            ("\"second\"", "\"second\", \"third\""),
            ("\"lookahead\": null", "\"lookahead\": null, \"added\": 1"),
            ("\"format\": 3", "\"format\": 4"),
        ];
        for (from, to) in edits {
            assert!(text.contains(from), "{from}");
            let edited = text.replacen(from, to, 1);
            assert!(
                matches!(read_sealed_card(path, &edited), Err(ModelFilesError::CardEdited { .. })),
                "edit {from} -> {to} accepted"
            );
        }
        // A card without its seal, or not a card at all.
        let mut unsealed = read.clone();
        unsealed.as_object_mut().unwrap().remove(CARD_SEAL);
        let unsealed = serde_json::to_string(&unsealed).unwrap();
        assert!(matches!(
            read_sealed_card(path, &unsealed),
            Err(ModelFilesError::CardEdited { .. })
        ));
        for bad in ["{ not json", "[1, 2]"] {
            assert!(matches!(
                read_sealed_card(path, bad),
                Err(ModelFilesError::CardUnreadable { .. })
            ));
        }
    }
}

/// The onboard aids a model's blobs are flown with: a config's `[sil]` tables `lookahead` and
/// `terminal` (an absent table: that aid not flown). What `ground model export --model DIR
/// --aids CONFIG` records in a card and the Python package's `fly_sil(aids=)` flies.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Aids {
    /// Rollout lookahead before the terminal cycles.
    pub lookahead: Option<onboard::lookahead::LookaheadSettings>,
    /// Terminal targeting over the last cycles.
    pub terminal: Option<onboard::terminal::TerminalSettings>,
}

/// The lookahead's margins and bound in words, those set (the thrust margin, the arrival margin,
/// the rollout budget): the one wording of the card's note and its lookahead section.
pub fn lookahead_terms(l: &onboard::lookahead::LookaheadSettings) -> Vec<String> {
    let mut terms = Vec::new();
    if l.thrust_margin > 0.0 {
        terms.push(format!("planning without {} of the thrust", l.thrust_margin));
    }
    match l.arrival_margin {
        0 => {}
        1 => terms.push("judging its rollouts 1 cycle before the arrival".to_string()),
        n => terms.push(format!("judging its rollouts {n} cycles before the arrival")),
    }
    if l.rollout_budget > 0 {
        terms.push(format!(
            "flying at most {} rollout steps a guidance cycle",
            l.rollout_budget
        ));
    }
    terms
}

impl Aids {
    /// How the blobs are flown, for the card's note.
    pub fn describe(&self) -> String {
        let lookahead = self.lookahead.map(|l| {
            let terms = lookahead_terms(&l);
            match terms.split_last() {
                None => "rollout lookahead".to_string(),
                Some((last, [])) => format!("rollout lookahead {last}"),
                Some((last, rest)) => format!("rollout lookahead {} and {last}", rest.join(", ")),
            }
        });
        let terminal = self
            .terminal
            .map(|t| format!("terminal targeting of the last {} cycles", t.cycles));
        match (lookahead, terminal) {
            (None, None) => "without onboard aids".to_string(),
            (Some(l), None) => format!("with {l}"),
            (None, Some(t)) => format!("with {t}"),
            (Some(l), Some(t)) => format!("with {l} and {t}"),
        }
    }
}
