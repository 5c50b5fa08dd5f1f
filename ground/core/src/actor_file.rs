//! The checked safetensors files of the learner (checkpoints, and a shipped model's
//! `actor.safetensors`) read without PyTorch: the CRC-32 the learner writes into their metadata,
//! and the flown actor's layers as the onboard export takes them.

use std::collections::HashMap;
use std::path::Path;

use shared::blob::Activation;
use shared::blob::FeatureLayout;
use shared::quantize::{DenseWeights, MlpWeights};

/// The metadata key of a checked file's checksum.
pub const CHECKSUM_KEY: &str = "crc32";
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why an actor file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ActorFileError {
    /// The file could not be read.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// It is not a safetensors file, or a tensor is not float32 or not finite.
    #[error("{0}")]
    Format(String),
    /// Its checksum is missing or does not match its tensors.
    #[error("{0}")]
    Corrupt(String),
    /// It holds no actor of this problem's layout (layers missing or of the wrong shape).
    #[error("{0}")]
    Layout(String),
}

/// CRC-32 of every tensor's name, dtype, shape and bytes, in name order: what a checked file
/// records under [`CHECKSUM_KEY`].
pub fn tensors_checksum(tensors: &safetensors::SafeTensors) -> u32 {
    let mut named = tensors.tensors();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    let mut digest = CRC.digest();
    for (name, view) in &named {
        digest.update(name.as_bytes());
        digest.update(format!("{:?}", view.dtype()).as_bytes());
        for d in view.shape() {
            digest.update(&(*d as u64).to_le_bytes());
        }
        digest.update(view.data());
    }
    digest.finalize()
}

/// Checks a checked file's recorded checksum against its tensors.
pub fn verify_checksum(bytes: &[u8], path: &Path) -> Result<(), ActorFileError> {
    let format = |e: safetensors::SafeTensorError| ActorFileError::Format(format!("{}: {e:?}", path.display()));
    let (_, header) = safetensors::SafeTensors::read_metadata(bytes).map_err(format)?;
    let tensors = safetensors::SafeTensors::deserialize(bytes).map_err(format)?;
    let recorded = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get(CHECKSUM_KEY))
        .ok_or_else(|| ActorFileError::Corrupt(format!("{} carries no checksum", path.display())))?;
    let found = format!("{:08x}", tensors_checksum(&tensors));
    if *recorded != found {
        return Err(ActorFileError::Corrupt(format!(
            "{}: checksum {found}, recorded {recorded}",
            path.display()
        )));
    }
    Ok(())
}

/// The flown actor of an actor file (`actor.l0.*`, `actor.l1.*`, ..., `actor.mean.*`; a
/// checkpoint's `average.actor.*` when it has an averaged actor, else `online.actor.*`) as the
/// layers of a network of input encoding `features`: ReLU hidden layers, tanh on the mean (the deterministic action).
pub fn read_actor(path: &Path, features: FeatureLayout) -> Result<MlpWeights, ActorFileError> {
    let bytes = std::fs::read(path)
        .map_err(|e| ActorFileError::Io(std::io::Error::new(e.kind(), format!("{}: {e}", path.display()))))?;
    verify_checksum(&bytes, path)?;
    let tensors = safetensors::SafeTensors::deserialize(&bytes)
        .map_err(|e| ActorFileError::Format(format!("{}: {e:?}", path.display())))?;
    let names = tensors.names();
    let prefix = ["average.actor.", "online.actor.", "actor."]
        .into_iter()
        .find(|p| names.iter().any(|n| n.starts_with(p)))
        .ok_or_else(|| ActorFileError::Layout(format!("{} holds no actor", path.display())))?;
    let mut layers = HashMap::new();
    for name in names.iter().filter_map(|n| n.strip_prefix(prefix)) {
        let view = tensors
            .tensor(&format!("{prefix}{name}"))
            .map_err(|e| ActorFileError::Format(format!("{}: {e:?}", path.display())))?;
        if view.dtype() != safetensors::Dtype::F32 {
            return Err(ActorFileError::Format(format!(
                "{prefix}{name} is {:?}, not F32",
                view.dtype()
            )));
        }
        let values: Vec<f32> = view
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if !values.iter().all(|v| v.is_finite()) {
            return Err(ActorFileError::Format(format!("{prefix}{name} has a non-finite value")));
        }
        layers.insert(name.to_string(), (view.shape().to_vec(), values));
    }
    actor_layers(features, &layers).map_err(ActorFileError::Layout)
}

/// The actor's layers from its tensors by name without the `actor.` prefix (`l0.weight`,
/// `l0.bias`, ..., `mean.weight`, `mean.bias`; shapes `[outputs, inputs]`): ReLU hidden
/// layers, tanh on the mean (the deterministic action). The one reading of an actor's layout,
/// for its file here and for a live learner's weights in the learning stack.
pub fn actor_layers(
    features: FeatureLayout,
    tensors: &HashMap<String, (Vec<usize>, Vec<f32>)>,
) -> Result<MlpWeights, String> {
    let mut names: Vec<String> = (0..)
        .map(|i| format!("l{i}"))
        .take_while(|n| tensors.contains_key(&format!("{n}.weight")))
        .collect();
    names.push("mean".into());
    let count = names.len();
    let layers = names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let missing = || format!("the actor has no {name} layer");
            let (shape, weights) = tensors.get(&format!("{name}.weight")).ok_or_else(missing)?;
            let (_, bias) = tensors.get(&format!("{name}.bias")).ok_or_else(missing)?;
            let [outputs, inputs] = shape[..] else {
                return Err(format!("actor {name}.weight has shape {shape:?}"));
            };
            Ok(DenseWeights {
                inputs,
                outputs,
                weights: weights.clone(),
                bias: bias.clone(),
                activation: if i + 1 == count {
                    Activation::Tanh
                } else {
                    Activation::Relu
                },
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(MlpWeights { features, layers })
}
