//! The SAC agent: actor, twin critics with Polyak-averaged targets, learned temperature.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use tch::nn::{self, VarStore};
use tch::{Device, Kind, Tensor};

use super::adam::{flatten_parameters, Adam};
use super::networks::{squashed_sample_gradients, Actor, TwinCritic};
use super::replay::Batch;
use super::SacConfig;

/// What one gradient update measured (means over the batch).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UpdateStats {
    /// Twin-critic loss 2 mean (Q_k(s, a) - y)^2 against the soft Bellman target y.
    pub critic_loss: f64,
    /// Soft actor loss mean(alpha log pi - min Q), without the behaviour-cloning term or scale.
    pub actor_loss: f64,
    /// Temperature loss -log alpha mean(log pi + target entropy).
    pub temperature_loss: f64,
    /// The temperature alpha this update used.
    pub temperature: f64,
    /// -E[log pi], the policy's entropy estimate.
    pub entropy: f64,
    /// Batch mean of Q1(s, a) at the stored actions.
    pub q_mean: f64,
    /// Mean cloning error of tanh(mean) against the demonstrated action ([`CloningLoss`]; 0
    /// without demonstrations).
    pub behaviour_cloning_loss: f64,
}

/// Why a checkpoint was refused.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The file could not be read or written.
    #[error("checkpoint I/O: {0}")]
    Io(std::io::Error),
    /// Not a safetensors file, or a tensor of an unsupported dtype (f32 and i64 only).
    #[error("checkpoint is not a readable safetensors file: {0}")]
    Format(String),
    /// The tensors do not fit this agent: one missing, one extra, or another shape.
    #[error("checkpoint does not match this agent: {0}")]
    Mismatch(String),
    /// The tensors do not match the checksum written with them (a flipped byte, a splice), or
    /// the file carries none (not written by [`Sac::save`]).
    #[error("checkpoint is corrupt: {0}")]
    Corrupt(String),
    /// A weight or optimiser moment is NaN or infinite: such a learner flies nothing sensible.
    #[error("checkpoint holds a non-finite value in {0}")]
    NonFinite(String),
}

// The checksum of the learner's safetensors files is ground-core's, which reads them without
// PyTorch too.
use ground_core::actor_file::{tensors_checksum, verify_checksum, ActorFileError, CHECKSUM_KEY};

/// Reads a file written by [`write_checked_safetensors`]: the tensors if the checksum matches
/// and every float is finite.
pub fn read_checked_safetensors(path: &Path) -> Result<Vec<(String, Tensor)>, CheckpointError> {
    read_labelled_safetensors(path).map(|(tensors, _)| tensors)
}

/// Named tensors, as a checkpoint holds them.
pub type NamedTensors = Vec<(String, Tensor)>;

/// [`read_checked_safetensors`] with the file's labels (its metadata but the checksum).
pub fn read_labelled_safetensors(path: &Path) -> Result<(NamedTensors, BTreeMap<String, String>), CheckpointError> {
    use safetensors::tensor::Dtype;
    let bytes = std::fs::read(path)
        .map_err(|e| CheckpointError::Io(std::io::Error::new(e.kind(), format!("{}: {e}", path.display()))))?;
    verify_checksum(&bytes, path).map_err(|e| match e {
        ActorFileError::Corrupt(why) => CheckpointError::Corrupt(why),
        other => CheckpointError::Format(other.to_string()),
    })?;
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)
        .map_err(|e| CheckpointError::Format(format!("{}: {e:?}", path.display())))?;
    let labels: BTreeMap<String, String> = header
        .metadata()
        .iter()
        .flatten()
        .filter(|(key, _)| key.as_str() != CHECKSUM_KEY)
        .map(|(key, value)| (key.clone(), value.clone()))
        .collect();
    let tensors = safetensors::SafeTensors::deserialize(&bytes)
        .map_err(|e| CheckpointError::Format(format!("{}: {e:?}", path.display())))?;
    let mut out = Vec::new();
    for (name, view) in tensors.tensors() {
        let kind = match view.dtype() {
            Dtype::F32 => Kind::Float,
            Dtype::I64 => Kind::Int64,
            other => return Err(CheckpointError::Format(format!("tensor {name} has dtype {other:?}"))),
        };
        if kind == Kind::Float
            && view
                .data()
                .chunks_exact(4)
                .any(|b| !f32::from_le_bytes([b[0], b[1], b[2], b[3]]).is_finite())
        {
            return Err(CheckpointError::NonFinite(name));
        }
        let shape: Vec<i64> = view.shape().iter().map(|&d| d as i64).collect();
        out.push((name, Tensor::from_data_size(view.data(), &shape, kind)));
    }
    Ok((out, labels))
}

/// Writes CPU tensors as safetensors with their checksum and `labels` in the metadata,
/// atomically (PyTorch opens the file with `safetensors.torch.load_file` as any other).
pub fn write_checked_safetensors(
    tensors: &[(String, Tensor)],
    labels: &BTreeMap<String, String>,
    path: &Path,
) -> Result<(), CheckpointError> {
    // The file is built in memory and written once, atomically: a failed write (a full disk)
    // is an I/O error naming the file, and leaves neither a part nor a temporary behind.
    let checked = checked_safetensors(tensors, labels)?;
    ground_core::io::atomic_write(path, &checked)
        .map_err(|e| CheckpointError::Io(std::io::Error::new(e.kind(), format!("{}: {e}", path.display()))))
}

/// The bytes [`write_checked_safetensors`] writes.
fn checked_safetensors(
    tensors: &[(String, Tensor)],
    labels: &BTreeMap<String, String>,
) -> Result<Vec<u8>, CheckpointError> {
    use safetensors::tensor::{Dtype, TensorView};
    let mut raw = Vec::with_capacity(tensors.len());
    for (name, tensor) in tensors {
        let cpu = tensor.to_device(Device::Cpu).contiguous();
        let dtype = match cpu.kind() {
            Kind::Float => Dtype::F32,
            Kind::Int64 => Dtype::I64,
            other => {
                return Err(CheckpointError::Format(format!(
                    "tensor {name} is {other:?}: f32 and i64 only"
                )))
            }
        };
        let mut bytes = vec![0u8; cpu.numel() * cpu.kind().elt_size_in_bytes()];
        cpu.f_copy_data_u8(&mut bytes, cpu.numel())
            .map_err(|e| CheckpointError::Format(format!("tensor {name}: {e}")))?;
        let shape: Vec<usize> = cpu.size().iter().map(|&d| d as usize).collect();
        raw.push((name.as_str(), dtype, shape, bytes));
    }
    let views = raw
        .iter()
        .map(|(name, dtype, shape, bytes)| {
            TensorView::new(*dtype, shape.clone(), bytes)
                .map(|view| (*name, view))
                .map_err(|e| CheckpointError::Format(format!("tensor {name}: {e:?}")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let plain = safetensors::serialize(views, &None).map_err(|e| CheckpointError::Format(format!("{e:?}")))?;
    let parsed =
        safetensors::SafeTensors::deserialize(&plain).map_err(|e| CheckpointError::Format(format!("{e:?}")))?;
    let mut metadata: HashMap<String, String> = labels.clone().into_iter().collect();
    metadata.insert(CHECKSUM_KEY.to_string(), format!("{:08x}", tensors_checksum(&parsed)));
    let checked = safetensors::serialize(parsed.tensors(), &Some(metadata))
        .map_err(|e| CheckpointError::Format(format!("{e:?}")))?;
    // With labels the metadata has several keys, which safetensors writes in a hash map's
    // random order: the header is written again with sorted keys, so the same state is the same
    // bytes (a resumed run's files equal an uninterrupted one's). Without, the bytes are as ever.
    if labels.is_empty() {
        Ok(checked)
    } else {
        sorted_header(&checked)
    }
}

/// A safetensors file with its JSON header's keys sorted (the metadata's too), padded to 8
/// bytes with spaces as safetensors pads it; the data after it unchanged.
fn sorted_header(bytes: &[u8]) -> Result<Vec<u8>, CheckpointError> {
    let bad = |why: &str| CheckpointError::Format(format!("safetensors header: {why}"));
    let len_bytes: [u8; 8] = bytes
        .get(..8)
        .and_then(|b| b.try_into().ok())
        .ok_or_else(|| bad("too short"))?;
    let len = usize::try_from(u64::from_le_bytes(len_bytes)).map_err(|_| bad("length"))?;
    let header = bytes.get(8..8 + len).ok_or_else(|| bad("truncated"))?;
    let entries: BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(header).map_err(|e| bad(&e.to_string()))?;
    let mut sorted: BTreeMap<String, serde_json::Value> = BTreeMap::new();
    for (key, value) in entries {
        let value = if key == "__metadata__" {
            let metadata: BTreeMap<String, String> = serde_json::from_value(value).map_err(|e| bad(&e.to_string()))?;
            serde_json::to_value(metadata).map_err(|e| bad(&e.to_string()))?
        } else {
            value
        };
        sorted.insert(key, value);
    }
    let mut text = serde_json::to_vec(&sorted).map_err(|e| bad(&e.to_string()))?;
    text.resize(text.len().div_ceil(8) * 8, b' ');
    let mut out = Vec::with_capacity(8 + text.len() + bytes.len() - 8 - len);
    out.extend_from_slice(&(text.len() as u64).to_le_bytes());
    out.extend_from_slice(&text);
    out.extend_from_slice(&bytes[8 + len..]);
    Ok(out)
}

/// Streams of the torch generator, one per use, so each draw is a function of the seed and a
/// counter that checkpoints restore (see [`Sac::noise_seed`]).
const UPDATE_NOISE: u64 = 0x5550_4441_5445;
const EXPLORATION_NOISE: u64 = 0x4558_504c_4f52;

/// splitmix64 of seed, stream and counter: well-mixed seeds for neighbouring counters.
fn noise_seed(seed: u64, stream: u64, counter: u64) -> i64 {
    let mut z = seed ^ stream.rotate_left(32) ^ counter.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) as i64
}

/// A SAC learner: squashed-Gaussian actor, twin critics with Polyak-averaged targets, learned
/// temperature alpha, their Adam optimisers and, when [`SacConfig::actor_averaging`] is set, an
/// averaged actor. Observations and actions are flat f32 rows; actions lie in [-1, 1].
pub struct Sac {
    /// The hyper-parameters. `hidden`, `learning_rate`, `target_entropy`,
    /// `initial_log_temperature` and `actor_averaging` are read at construction only; the others
    /// where they are used, so a phase may change them (RL from scratch sets `behaviour_cloning` to 0).
    pub config: SacConfig,
    obs_dim: usize,
    act_dim: usize,
    device: Device,
    actor_store: VarStore,
    actor: Actor,
    critic_store: VarStore,
    critics: TwinCritic,
    target_store: VarStore,
    targets: TwinCritic,
    /// The target critics' parameters as one buffer, laid out as the online critics' optimiser
    /// buffer, for Polyak averaging in one kernel.
    target_flat: Tensor,
    temperature_store: VarStore,
    log_temperature: Tensor,
    actor_optimizer: Adam,
    critic_optimizer: Adam,
    temperature_optimizer: Adam,
    /// Where each of an optimiser's parameters sits in its network's own list (the order the
    /// hand-written backward passes return gradients in).
    actor_order: Vec<usize>,
    critic_order: Vec<usize>,
    target_entropy: f64,
    /// The behaviour-cloning error (see [`CloningLoss`]).
    cloning: Box<dyn CloningLoss>,
    /// The averaged actor of `config.actor_averaging` (None when 0).
    average: Option<AveragedActor>,
    /// Gradient updates done so far.
    pub updates: u64,
    /// Seed of the torch generator's draws: update `n` draws its noise from a generator seeded
    /// by (seed, n), exploration step `k` from (seed, k). The draws are then a function of what a
    /// checkpoint holds, so a resumed phase repeats an uninterrupted one exactly (a generator
    /// state carried across a restart would need saving, and libtorch's is not exposed by tch).
    pub noise_seed: u64,
    /// What the learner was made for, by name (the experiment's mission family, say): written
    /// into every checkpoint's metadata, and a checkpoint whose label under one of these names
    /// differs is refused by [`Sac::load`] with both values. Unlabelled files load as before.
    pub labels: BTreeMap<String, String>,
}

/// A Polyak-averaged copy of the actor: its own store (names `actor.*`, as the online one) and
/// its parameters as one buffer laid out as the actor optimiser's, so averaging is one lerp.
struct AveragedActor {
    store: VarStore,
    actor: Actor,
    flat: Tensor,
}

/// The mean of a per-row error over a batch's demonstration rows (`demos` 1 or 0): the cloning
/// loss; 0 for a batch without demonstrations.
fn over_demonstrations(error: &Tensor, demos: &Tensor) -> Tensor {
    (error * demos).sum(Kind::Float) / demos.sum(Kind::Float).clamp_min(1.0)
}

/// An actor file's tensors (of [`Sac::save_flown_actor`]), refused unless it holds exactly the
/// tensors `vars` names, whatever their shapes.
fn read_actor_file(path: &Path, vars: &HashMap<String, Tensor>) -> Result<HashMap<String, Tensor>, CheckpointError> {
    let tensors: HashMap<String, Tensor> = read_checked_safetensors(path)?.into_iter().collect();
    if let Some(extra) = tensors.keys().find(|n| !vars.contains_key(*n)) {
        return Err(CheckpointError::Mismatch(format!(
            "{extra} is no actor tensor of this network (an actor file holds actor.* only)"
        )));
    }
    if let Some(missing) = vars.keys().find(|n| !tensors.contains_key(*n)) {
        return Err(CheckpointError::Mismatch(format!("missing tensor {missing}")));
    }
    Ok(tensors)
}

/// A mini-batch as tensors on the learner's device.
struct BatchTensors {
    size: usize,
    obs: Tensor,
    actions: Tensor,
    rewards: Tensor,
    next_obs: Tensor,
    /// gamma (1 - done): the discount a transition's bootstrapped value takes.
    continuation: Tensor,
    demonstrations: Tensor,
    any_demonstration: bool,
}

/// The critic step's loss, its gradients ([`TwinCritic::parameters`]' order) and Q1's batch mean.
struct CriticGradients {
    loss: Tensor,
    q_mean: Tensor,
    grads: Vec<Tensor>,
}

/// The actor step's gradients ([`Actor::parameters`]' order), its soft loss, the sample's
/// log-densities and the cloning error (0 for a batch without demonstrations).
struct ActorGradients {
    grads: Vec<Tensor>,
    soft_loss: Tensor,
    log_prob: Tensor,
    cloning_loss: f64,
}

/// For each of `optimised`, its index in `network`: both list the same tensors (shared storage),
/// perhaps in different orders (a store's creation order against a network's layer order).
fn parameter_order(optimised: &[Tensor], network: &[Tensor]) -> Vec<usize> {
    optimised
        .iter()
        .map(|p| {
            network
                .iter()
                .position(|q| q.data_ptr() == p.data_ptr() && q.size() == p.size())
                .expect("an optimised tensor the network does not list")
        })
        .collect()
}

/// Gradients in a network's order, rearranged into an optimiser's ([`parameter_order`]).
fn reorder(grads: &[Tensor], order: &[usize]) -> Vec<Tensor> {
    order.iter().map(|&i| grads[i].shallow_clone()).collect()
}

fn tensor_2d(data: &[f32], rows: usize, cols: usize, device: Device) -> Tensor {
    Tensor::from_slice(data)
        .view([rows as i64, cols as i64])
        .to_device(device)
}

/// gamma (1 - done) per transition: a terminal transition bootstraps nothing.
fn continuation(dones: &[f32], discount: f64) -> Vec<f32> {
    let gamma = discount as f32;
    dones.iter().map(|&done| gamma * (1.0 - done)).collect()
}

/// The soft Bellman target y = r + gamma (1 - done) (min Q'(s', a') - alpha log pi(a'|s')), the
/// entropy bonus in the bootstrapped value; `continuation` is gamma (1 - done).
pub fn soft_bellman_target(
    rewards: &Tensor,
    continuation: &Tensor,
    q_next: &Tensor,
    log_prob_next: &Tensor,
    temperature: &Tensor,
) -> Tensor {
    let soft_value = q_next - temperature * log_prob_next;
    rewards + continuation * soft_value
}

/// The behaviour-cloning error of a batch: the policy's deterministic actions (tanh of the mean)
/// and the demonstrated ones in, both [batch, act_dim], one error per row out, [batch, 1]. The
/// agent averages it over the batch's demonstrations and weighs it by
/// [`SacConfig::behaviour_cloning`]; gradients flow through `policy_action`.
pub trait CloningLoss: Send + Sync {
    /// The error of each row of `policy_action` against `demo_action`, shape [batch, 1].
    fn error(&self, policy_action: &Tensor, demo_action: &Tensor) -> Tensor;

    /// The action dimension the error is defined for (`None`: any); [`Sac::with_cloning_loss`]
    /// refuses an agent of another one.
    fn action_dim(&self) -> Option<usize> {
        None
    }
}

/// The default cloning error, the squared distance of the action vectors: |tanh(mean) - a_demo|^2.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ActionError;

impl CloningLoss for ActionError {
    fn error(&self, policy_action: &Tensor, demo_action: &Tensor) -> Tensor {
        (policy_action - demo_action)
            .square()
            .sum_dim_intlist(-1, true, Kind::Float)
    }
}

impl Sac {
    /// An agent whose behaviour-cloning term is the squared action distance ([`ActionError`]).
    pub fn new(config: SacConfig, obs_dim: usize, act_dim: usize, device: Device) -> Self {
        Self::with_cloning_loss(config, obs_dim, act_dim, device, Box::new(ActionError))
    }

    /// An agent whose behaviour-cloning term is `cloning` (used when
    /// [`SacConfig::behaviour_cloning`] is positive, and reported in [`UpdateStats`] always).
    pub fn with_cloning_loss(
        config: SacConfig,
        obs_dim: usize,
        act_dim: usize,
        device: Device,
        cloning: Box<dyn CloningLoss>,
    ) -> Self {
        let actor_store = VarStore::new(device);
        let actor = Actor::new(&(actor_store.root() / "actor"), obs_dim, act_dim, &config.hidden);
        let critic_store = VarStore::new(device);
        let critics = TwinCritic::new(&(critic_store.root() / "critic"), obs_dim, act_dim, &config.hidden);
        let mut target_store = VarStore::new(device);
        let targets = TwinCritic::new(&(target_store.root() / "critic"), obs_dim, act_dim, &config.hidden);
        target_store.freeze();
        let critic_optimizer = Adam::new(critic_store.trainable_variables(), config.learning_rate);
        // Both stores were built by the same constructor, so their creation orders (and the
        // flat layouts) correspond parameter for parameter.
        let target_params = target_store.trainable_variables();
        debug_assert!(target_params
            .iter()
            .zip(critic_store.trainable_variables())
            .all(|(t, s)| t.size() == s.size()));
        let mut target_flat = flatten_parameters(&target_params);
        tch::no_grad(|| target_flat.copy_(critic_optimizer.flat_parameters()));
        let temperature_store = VarStore::new(device);
        let log_temperature =
            temperature_store
                .root()
                .var("log_temperature", &[1], nn::Init::Const(config.initial_log_temperature));
        let lr = config.learning_rate;
        let actor_optimizer = Adam::new(actor_store.trainable_variables(), lr);
        let temperature_optimizer = Adam::new(vec![log_temperature.shallow_clone()], lr);
        if let Some(needed) = cloning.action_dim() {
            assert!(
                needed == act_dim,
                "the behaviour-cloning loss needs a {needed}-component action, this agent has {act_dim}"
            );
        }
        let target_entropy = config.target_entropy.unwrap_or(-(act_dim as f64));
        let actor_order = parameter_order(actor_optimizer.parameters(), &actor.parameters());
        let critic_order = parameter_order(critic_optimizer.parameters(), &critics.parameters());
        let average = (config.actor_averaging > 0.0).then(|| {
            let mut store = VarStore::new(device);
            let actor = Actor::zeroed(&(store.root() / "actor"), obs_dim, act_dim, &config.hidden);
            store.freeze();
            // Same constructor as the online actor, so the flat layouts correspond.
            let mut flat = flatten_parameters(&store.trainable_variables());
            tch::no_grad(|| flat.copy_(actor_optimizer.flat_parameters()));
            AveragedActor { store, actor, flat }
        });
        Self {
            config,
            obs_dim,
            act_dim,
            device,
            actor_store,
            actor,
            critic_store,
            critics,
            target_store,
            targets,
            target_flat,
            temperature_store,
            log_temperature,
            actor_optimizer,
            critic_optimizer,
            temperature_optimizer,
            actor_order,
            critic_order,
            target_entropy,
            cloning,
            average,
            updates: 0,
            noise_seed: 0,
            labels: BTreeMap::new(),
        }
    }

    /// Observation features the networks take.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Action components the actor outputs.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    /// The current temperature alpha = exp(log alpha).
    pub fn temperature(&self) -> f64 {
        self.log_temperature.exp().double_value(&[0])
    }

    /// The actor that is evaluated and flown: the averaged one when averaging is on.
    fn flown_actor(&self) -> &Actor {
        self.average.as_ref().map_or(&self.actor, |a| &a.actor)
    }

    /// Deterministic actions for `rows` observations laid out row-major: tanh of the mean of
    /// the flown actor (see [`SacConfig::actor_averaging`]), what is evaluated and flown.
    pub fn act(&self, obs: &[f32], rows: usize) -> Vec<f32> {
        tch::no_grad(|| {
            let o = tensor_2d(obs, rows, self.obs_dim, self.device);
            let a = self.flown_actor().deterministic(&o);
            Vec::<f32>::try_from(a.to_device(Device::Cpu).view([-1])).unwrap_or_default()
        })
    }

    /// Exploration actions sampled from the online actor at environment step `step` (the
    /// noise is a function of [`Sac::noise_seed`] and `step`).
    pub fn explore(&self, obs: &[f32], rows: usize, step: u64) -> Vec<f32> {
        tch::manual_seed(noise_seed(self.noise_seed, EXPLORATION_NOISE, step));
        tch::no_grad(|| {
            let o = tensor_2d(obs, rows, self.obs_dim, self.device);
            let a = self.actor.sample(&o).action;
            Vec::<f32>::try_from(a.to_device(Device::Cpu).view([-1])).unwrap_or_default()
        })
    }

    /// The twin-critic minimum Q(s, a) for a batch (diagnostics and tests).
    pub fn q_value(&self, obs: &[f32], actions: &[f32], rows: usize) -> Vec<f32> {
        tch::no_grad(|| {
            let o = tensor_2d(obs, rows, self.obs_dim, self.device);
            let a = tensor_2d(actions, rows, self.act_dim, self.device);
            let q = self.critics.min_q(&o, &a);
            Vec::<f32>::try_from(q.to_device(Device::Cpu).view([-1])).unwrap_or_default()
        })
    }

    /// One SAC gradient update on a mini-batch. The gradients are written out by hand
    /// (`Sac::critic_gradients`, `Sac::actor_gradients`) rather than recorded and replayed
    /// by autograd: the same arithmetic without a graph of some sixty nodes per update, whose
    /// bookkeeping cost a seventh of an update at the thesis's sizes (5.4 against 4.6 ms on one
    /// thread). A test checks them against autograd on the losses as written there.
    pub fn update(&mut self, batch: &Batch) -> UpdateStats {
        tch::manual_seed(noise_seed(self.noise_seed, UPDATE_NOISE, self.updates));
        let batch = self.batch_tensors(batch);
        let stats = tch::no_grad(|| {
            let temperature = self.log_temperature.exp();
            // 1. Critics regress on the soft Bellman target.
            let critic = self.critic_gradients(&batch, &temperature);
            self.critic_optimizer.step(&reorder(&critic.grads, &self.critic_order));
            // 2. The actor maximises the soft value under the updated critics.
            let actor = self.actor_gradients(&batch, &temperature);
            self.actor_optimizer.step(&reorder(&actor.grads, &self.actor_order));
            // 3. Temperature: L_alpha = -mean(log alpha (log pi + target entropy)), raising alpha
            //    when the entropy is below target and lowering it when above.
            let log_prob_gap = (&actor.log_prob + self.target_entropy).mean(Kind::Float);
            let reported = Tensor::stack(
                &[
                    &critic.loss,
                    &actor.soft_loss,
                    &log_prob_gap,
                    &self.log_temperature.view([]),
                    &critic.q_mean,
                ],
                0,
            );
            self.temperature_optimizer.step(&[-log_prob_gap.view([1])]);
            // One transfer for the figures (one wait on a GPU).
            let v = Vec::<f64>::try_from(reported.to_kind(Kind::Double)).unwrap_or_else(|_| vec![f64::NAN; 5]);
            UpdateStats {
                critic_loss: v[0],
                actor_loss: v[1],
                temperature_loss: -v[3] * v[2],
                temperature: v[3].exp(),
                entropy: self.target_entropy - v[2],
                q_mean: v[4],
                behaviour_cloning_loss: actor.cloning_loss,
            }
        });
        self.average_actor();
        self.clamp_temperature();
        // 4. Targets trail the online critics: theta' <- (1 - tau) theta' + tau theta.
        self.polyak_update();
        self.updates += 1;
        stats
    }

    /// The batch's columns packed into one buffer and sent as one tensor (one transfer, a few
    /// operations instead of three per column), then viewed as [batch, width] each.
    fn batch_tensors(&self, batch: &Batch) -> BatchTensors {
        let b = batch.size;
        let continuation = continuation(&batch.dones, self.config.discount);
        let columns: [(&[f32], usize); 6] = [
            (&batch.obs, self.obs_dim),
            (&batch.actions, self.act_dim),
            (&batch.rewards, 1),
            (&batch.next_obs, self.obs_dim),
            (&continuation, 1),
            (&batch.demonstrations, 1),
        ];
        let packed: Vec<f32> = columns.iter().flat_map(|(data, _)| data.iter().copied()).collect();
        let lengths: Vec<i64> = columns.iter().map(|(_, width)| (b * width) as i64).collect();
        let mut tensors = Tensor::from_slice(&packed)
            .to_device(self.device)
            .split_with_sizes(lengths.as_slice(), 0)
            .into_iter()
            .zip(columns)
            .map(|(tensor, (_, width))| tensor.view([b as i64, width as i64]));
        let mut next = || tensors.next().expect("six columns");
        BatchTensors {
            size: b,
            obs: next(),
            actions: next(),
            rewards: next(),
            next_obs: next(),
            continuation: next(),
            demonstrations: next(),
            any_demonstration: batch.demonstrations.iter().any(|&d| d > 0.0),
        }
    }

    /// The critics' loss L_Q = 2 mean_{k, i} (Q_k(s_i, a_i) - y_i)^2, y the soft Bellman target
    /// from the target critics and a fresh action of the current policy at s', and its gradients
    /// in [`TwinCritic::parameters`]' order. Draws the target action's noise.
    fn critic_gradients(&self, batch: &BatchTensors, temperature: &Tensor) -> CriticGradients {
        let next = self.actor.sample(&batch.next_obs);
        let q_next = self.targets.min_q(&batch.next_obs, &next.action);
        let soft_target = soft_bellman_target(
            &batch.rewards,
            &batch.continuation,
            &q_next,
            &next.log_prob,
            temperature,
        );
        let pass = self.critics.forward_recorded(&batch.obs, &batch.actions);
        let residual = &pass.q - &soft_target;
        CriticGradients {
            loss: residual.square().mean(Kind::Float) * 2.0,
            q_mean: pass.q.get(0).mean(Kind::Float),
            grads: self
                .critics
                .weight_gradients(&pass, &(&residual * (2.0 / batch.size as f64))),
        }
    }

    /// The actor's loss and its gradients in [`Actor::parameters`]' order: the soft loss
    /// L_pi = mean_i(alpha log pi(a_i|s_i) - min_k Q_k(s_i, a_i)), a = tanh(mean + std noise),
    /// alone, or with a cloning weight w as L_pi / mean_i|min_k Q_k| + w L_bc (TD3+BC's
    /// normalisation, the scale held constant). Draws the sample's noise.
    fn actor_gradients(&self, batch: &BatchTensors, temperature: &Tensor) -> ActorGradients {
        let b = batch.size as f64;
        let (sample, actor_pass) = self.actor.sample_recorded(&batch.obs);
        let critic_pass = self.critics.forward_recorded(&batch.obs, &sample.action);
        let (q_pi, chosen) = critic_pass.q.min_dim(0, false);
        let soft_loss = (temperature * &sample.log_prob - &q_pi).mean(Kind::Float);
        // The soft loss's scale: 1 alone (None), 1 / mean|min Q| beside a cloning term.
        let (scale, grad_mean_cloning, cloning_loss) = if self.config.behaviour_cloning > 0.0 {
            let (loss, grad) = self.cloning_gradient(&sample.mean_action(), &batch.actions, &batch.demonstrations);
            let scale = q_pi.abs().mean(Kind::Float).clamp_min(1e-6).reciprocal();
            (Some(scale), Some(grad * self.config.behaviour_cloning), loss)
        } else if batch.any_demonstration {
            // Reported, not weighed.
            let error = self.cloning.error(&sample.mean_action(), &batch.actions);
            let loss = over_demonstrations(&error, &batch.demonstrations).double_value(&[]);
            (None, None, loss)
        } else {
            (None, None, 0.0)
        };
        // dL/d(min Q) = -scale / batch in every row; dL/d(log pi) = scale alpha / batch.
        let min_gradient = self.critics.min_action_gradient(&critic_pass, &chosen.view([-1]));
        let (grad_action, grad_log_prob) = match &scale {
            Some(scale) => (min_gradient * (scale * (-1.0 / b)), scale * temperature * (1.0 / b)),
            None => (min_gradient * (-1.0 / b), temperature * (1.0 / b)),
        };
        let (grad_mean, grad_log_std) = squashed_sample_gradients(&sample, &actor_pass, &grad_action, &grad_log_prob);
        let grad_mean = match grad_mean_cloning {
            Some(cloning) => grad_mean + cloning,
            None => grad_mean,
        };
        ActorGradients {
            grads: self.actor.backward(&actor_pass, &grad_mean, &grad_log_std),
            soft_loss,
            log_prob: sample.log_prob,
            cloning_loss,
        }
    }

    /// The cloning term's value L_bc = sum(error * demo) / max(sum(demo), 1) and its gradient with
    /// respect to the actor's mean, from its deterministic action tanh(mean): the error is any
    /// [`CloningLoss`], so its own derivative is taken by autograd on that small graph alone.
    fn cloning_gradient(&self, mean_action: &Tensor, demo_actions: &Tensor, demos: &Tensor) -> (f64, Tensor) {
        let policy_action = mean_action.detach().set_requires_grad(true);
        let (loss, grad) = tch::with_grad(|| {
            let loss = over_demonstrations(&self.cloning.error(&policy_action, demo_actions), demos);
            let grad = Tensor::run_backward(&[&loss], &[&policy_action], false, false);
            (loss, grad)
        });
        let grad_mean = &grad[0] * (1.0 - mean_action.square());
        (loss.double_value(&[]), grad_mean)
    }

    /// Applies `max_log_temperature` (after each temperature step and after a load, so a
    /// checkpoint from an uncapped phase does not fly one update above the cap).
    fn clamp_temperature(&mut self) {
        if let Some(cap) = self.config.max_log_temperature {
            tch::no_grad(|| {
                let _ = self.log_temperature.clamp_max_(cap);
            });
        }
    }

    fn polyak_update(&mut self) {
        let tau = self.config.target_smoothing;
        tch::no_grad(|| {
            let _ = self.target_flat.lerp_(self.critic_optimizer.flat_parameters(), tau);
        });
    }

    /// Named tensors of the whole learner state (networks, targets, temperature, optimisers).
    fn named_state(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::new();
        for (prefix, store) in [
            ("online", &self.actor_store),
            ("online", &self.critic_store),
            ("target", &self.target_store),
        ] {
            let mut vars: Vec<_> = store.variables().into_iter().collect();
            vars.sort_by(|a, b| a.0.cmp(&b.0));
            out.extend(vars.into_iter().map(|(n, t)| (format!("{prefix}.{n}"), t)));
        }
        if let Some(average) = &self.average {
            let mut vars: Vec<_> = average.store.variables().into_iter().collect();
            vars.sort_by(|a, b| a.0.cmp(&b.0));
            out.extend(vars.into_iter().map(|(n, t)| (format!("average.{n}"), t)));
        }
        out.push(("online.log_temperature".into(), self.log_temperature.shallow_clone()));
        out.extend(self.actor_optimizer.state("adam.actor"));
        out.extend(self.critic_optimizer.state("adam.critic"));
        out.extend(self.temperature_optimizer.state("adam.temperature"));
        out.push(("updates".into(), Tensor::from_slice(&[self.updates as i64])));
        out
    }

    /// Writes the full learner state as one safetensors file (PyTorch users open it with
    /// `safetensors.torch.load_file`; the actor is under `online.actor.*`, and the averaged actor
    /// that is flown when `actor_averaging` is on under `average.actor.*`), atomically.
    pub fn save(&self, path: &Path) -> Result<(), CheckpointError> {
        write_checked_safetensors(&self.named_state(), &self.labels, path)
    }

    /// Restores a state written by [`Sac::save`]; the checksum must match, every value be
    /// finite and every tensor be present with its shape.
    pub fn load(&mut self, path: &Path) -> Result<(), CheckpointError> {
        let (tensors, labels) = read_labelled_safetensors(path)?;
        for (name, theirs) in &labels {
            if let Some(ours) = self.labels.get(name).filter(|ours| *ours != theirs) {
                return Err(CheckpointError::Mismatch(format!(
                    "{}: the checkpoint's {name} is {theirs}, this learner's {ours}",
                    path.display()
                )));
            }
        }
        let tensors: HashMap<String, Tensor> = tensors.into_iter().collect();
        let get = |name: &str| tensors.get(name).map(|t| t.to_device(self.device));
        // Check everything before touching anything, so a mismatch leaves the agent intact.
        if self.average.is_none() && tensors.keys().any(|n| n.starts_with("average.")) {
            // Loading it would silently fly the online actor instead of the averaged one.
            return Err(CheckpointError::Mismatch(
                "the checkpoint has an averaged actor (sac.actor_averaging > 0), this agent has none".into(),
            ));
        }
        for (name, dst) in self.named_state() {
            let src = get(&name).ok_or_else(|| CheckpointError::Mismatch(format!("missing tensor {name}")))?;
            if src.size() != dst.size() {
                return Err(CheckpointError::Mismatch(format!(
                    "tensor {name} has shape {:?}, this agent expects {:?}",
                    src.size(),
                    dst.size()
                )));
            }
        }
        for (name, dst) in self.named_state() {
            if name.starts_with("adam.") || name == "updates" {
                continue;
            }
            let mut dst = dst;
            tch::no_grad(|| dst.copy_(&get(&name).unwrap_or_else(|| dst.shallow_clone())));
        }
        let adam = |opt: &mut Adam, prefix: &str| {
            opt.load_state(prefix, &|n| get(n))
                .map_err(|e| CheckpointError::Mismatch(e.to_string()))
        };
        adam(&mut self.actor_optimizer, "adam.actor")?;
        adam(&mut self.critic_optimizer, "adam.critic")?;
        adam(&mut self.temperature_optimizer, "adam.temperature")?;
        self.updates = get("updates").map(|t| t.int64_value(&[0]) as u64).unwrap_or(0);
        self.clamp_temperature();
        Ok(())
    }

    /// One update of the actor alone on the behaviour-cloning error of the batch's
    /// demonstrations (its deterministic action against the demonstrated one): no critic,
    /// temperature or target step, and no draw. Relabelling rounds that start from a shipped
    /// actor, whose critics were not kept, train this way. Returns the cloning error.
    pub fn cloning_update(&mut self, batch: &Batch) -> f64 {
        let b = batch.size;
        let obs = tensor_2d(&batch.obs, b, self.obs_dim, self.device);
        let actions = tensor_2d(&batch.actions, b, self.act_dim, self.device);
        let demos = tensor_2d(&batch.demonstrations, b, 1, self.device);
        let error = self.cloning.error(&self.actor.deterministic(&obs), &actions);
        let loss = over_demonstrations(&error, &demos);
        self.actor_optimizer.backward_step(&loss);
        self.average_actor();
        self.updates += 1;
        loss.double_value(&[])
    }

    /// The gradient of `sum(grad_actions . pi(obs))` with respect to the observations, for
    /// `rows` observations and the flown actor's deterministic actions: a vector-Jacobian
    /// product of the policy, which backpropagation through a flight chains from step to step.
    /// Row-major, `rows x obs_dim`.
    pub fn action_input_gradient(&self, obs: &[f32], grad_actions: &[f32], rows: usize) -> Vec<f32> {
        let o = tensor_2d(obs, rows, self.obs_dim, self.device).set_requires_grad(true);
        let g = tensor_2d(grad_actions, rows, self.act_dim, self.device);
        let a = self.flown_actor().deterministic(&o);
        let grads = Tensor::run_backward(&[(a * g).sum(Kind::Float)], &[&o], false, false);
        Vec::<f32>::try_from(grads[0].to_device(Device::Cpu).view([-1])).unwrap_or_default()
    }

    /// One Adam step of the online actor along a gradient given through its actions: the loss
    /// is `sum(grad_actions . pi(obs))` over `rows` observations, so `grad_actions` holding
    /// d(objective)/d(action) for each row makes this a step down the objective (fine-tuning
    /// through the dynamics). The averaged actor, when there is one, follows as after any update.
    pub fn action_gradient_step(&mut self, obs: &[f32], grad_actions: &[f32], rows: usize) {
        let o = tensor_2d(obs, rows, self.obs_dim, self.device);
        let g = tensor_2d(grad_actions, rows, self.act_dim, self.device);
        let loss = (self.actor.deterministic(&o) * g).sum(Kind::Float);
        self.actor_optimizer.backward_step(&loss);
        self.average_actor();
        self.updates += 1;
    }

    /// The averaged actor takes a step towards the online one.
    fn average_actor(&mut self) {
        if let Some(average) = &mut self.average {
            // A plain running mean until it would weigh the newest iterate less than tau, then the
            // exponential average: the random initial weights do not linger in it.
            let tau = self.config.actor_averaging.max(1.0 / (self.updates as f64 + 2.0));
            tch::no_grad(|| {
                let _ = average.flat.lerp_(self.actor_optimizer.flat_parameters(), tau);
            });
        }
    }

    /// Starts this learner from an actor file of [`Sac::save_flown_actor`] (a shipped model's):
    /// the online actor and, when averaging is on, the averaged one both take its weights; the
    /// critics and optimisers stay as built. An actor with narrower hidden layers (the same
    /// depth, features and actions) is widened without changing its output: each added unit
    /// keeps this learner's random initial inputs and starts with zero weight into the layer
    /// above and the heads, so training grows the actor from its own function. Returns the
    /// file's hidden widths.
    pub fn start_from_actor(&mut self, path: &Path) -> Result<Vec<usize>, CheckpointError> {
        let vars = self.actor_store.variables();
        let tensors = read_actor_file(path, &vars)?;
        for (name, dst) in &vars {
            let (s, d) = (tensors[name].size(), dst.size());
            let fits = s.len() == d.len() && s.iter().zip(&d).all(|(a, b)| a <= b);
            // The features and the actions are no widths to grow.
            let head = name.starts_with("actor.mean.") || name.starts_with("actor.log_std.");
            let fixed = fits && ((name == "actor.l0.weight" && s[1] != d[1]) || (head && s[0] != d[0]));
            if !fits || fixed {
                return Err(CheckpointError::Mismatch(format!(
                    "tensor {name} has shape {s:?}, this actor expects {d:?} (or narrower hidden layers)"
                )));
            }
        }
        for (name, dst) in vars {
            let src = tensors[&name].to_device(self.device);
            let mut kept = dst.narrow(0, 0, src.size()[0]);
            tch::no_grad(|| {
                if src.dim() == 2 {
                    // The kept units read nothing from the added ones.
                    let _ = kept.zero_();
                    kept.narrow(1, 0, src.size()[1]).copy_(&src);
                } else {
                    kept.copy_(&src);
                }
            });
        }
        if let Some(average) = &mut self.average {
            // The two flat buffers are laid out alike (same constructor).
            tch::no_grad(|| {
                average.flat.copy_(self.actor_optimizer.flat_parameters());
            });
        }
        let mut widths = Vec::new();
        while let Some(bias) = tensors.get(&format!("actor.l{}.bias", widths.len())) {
            widths.push(bias.size()[0] as usize);
        }
        Ok(widths)
    }

    /// Writes the flown actor alone (the averaged one when averaging is on) as
    /// `actor.l0.weight`, ..., `actor.mean.*`, `actor.log_std.*`, checksummed: what a shipped
    /// model carries ([`Sac::load_actor`] reads it back).
    pub fn save_flown_actor(&self, path: &Path) -> Result<(), CheckpointError> {
        write_checked_safetensors(&self.flown_actor_tensors(), &BTreeMap::new(), path)
    }

    /// The bytes [`Sac::save_flown_actor`] writes, to compare with an actor file.
    pub fn flown_actor_bytes(&self) -> Result<Vec<u8>, CheckpointError> {
        checked_safetensors(&self.flown_actor_tensors(), &BTreeMap::new())
    }

    /// The flown actor's tensors by name.
    fn flown_actor_tensors(&self) -> Vec<(String, Tensor)> {
        let store = self.average.as_ref().map_or(&self.actor_store, |a| &a.store);
        let mut vars: Vec<(String, Tensor)> = store.variables().into_iter().collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        vars
    }

    /// Loads an actor file of [`Sac::save_flown_actor`] into the flown actor (for evaluation:
    /// the critics and optimisers stay as they are). Every actor tensor must be there with its
    /// shape, and nothing else.
    pub fn load_actor(&mut self, path: &Path) -> Result<(), CheckpointError> {
        let store = self.average.as_ref().map_or(&self.actor_store, |a| &a.store);
        let vars = store.variables();
        let tensors = read_actor_file(path, &vars)?;
        for (name, dst) in &vars {
            let src = &tensors[name];
            if src.size() != dst.size() {
                return Err(CheckpointError::Mismatch(format!(
                    "tensor {name} has shape {:?}, this actor expects {:?}",
                    src.size(),
                    dst.size()
                )));
            }
        }
        for (name, mut dst) in vars {
            tch::no_grad(|| dst.copy_(&tensors[&name].to_device(self.device)));
        }
        Ok(())
    }

    /// The flown actor's weights (the averaged one when averaging is on) by layer name (`l0`,
    /// `l1`, `mean`, `log_std`; weight [out, in]) for the onboard exporter.
    pub fn actor_weights(&self) -> HashMap<String, (Vec<i64>, Vec<f32>)> {
        self.average
            .as_ref()
            .map_or(&self.actor_store, |a| &a.store)
            .variables()
            .into_iter()
            .map(|(name, t)| {
                let shape = t.size();
                let data = Vec::<f32>::try_from(t.to_device(Device::Cpu).detach().view([-1])).unwrap_or_default();
                (name.trim_start_matches("actor.").to_string(), (shape, data))
            })
            .collect()
    }

    /// Number of trainable parameters in (actor, both critics).
    pub fn parameter_counts(&self) -> (i64, i64) {
        let count = |s: &VarStore| s.trainable_variables().iter().map(|t| t.numel() as i64).sum();
        (count(&self.actor_store), count(&self.critic_store))
    }

    /// (target, online) critic parameter pairs matched by name (independently of the flat
    /// layouts Polyak averaging runs on), for inspection.
    pub fn target_pairs(&self) -> Vec<(Tensor, Tensor)> {
        let online = self.critic_store.variables();
        let mut targets: Vec<_> = self.target_store.variables().into_iter().collect();
        targets.sort_by(|a, b| a.0.cmp(&b.0));
        targets
            .into_iter()
            .filter_map(|(name, t)| online.get(&name).map(|s| (t, s.shallow_clone())))
            .collect()
    }

    /// The temperature's variable store (one scalar, log alpha).
    pub fn temperature_store(&self) -> &VarStore {
        &self.temperature_store
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sac::replay::{sampler, ReplayBuffer, Transition};
    use crate::sac::torch_lock;

    fn tiny(config: SacConfig) -> Sac {
        tch::manual_seed(11);
        Sac::new(
            SacConfig {
                hidden: vec![32, 32],
                batch_size: 64,
                ..config
            },
            1,
            1,
            Device::Cpu,
        )
    }

    /// A one-step bandit: the observation is constant, reward -(a - 0.5)^2, every step terminal.
    fn bandit_buffer(n: usize) -> ReplayBuffer {
        let mut buf = ReplayBuffer::new(1, 1, n);
        for k in 0..n {
            let a = -1.0 + 2.0 * (k as f32 + 0.5) / n as f32;
            buf.push(&Transition {
                obs: &[1.0],
                action: &[a],
                reward: -(a - 0.5) * (a - 0.5),
                next_obs: &[1.0],
                done: true,
                demonstration: false,
            });
        }
        buf
    }

    /// A batch of `n` pseudo-random transitions (every third a demonstration, every fifth
    /// terminal), drawn from a buffer of 4n.
    fn random_batch(obs_dim: usize, act_dim: usize, n: usize) -> Batch {
        let value = |k: usize, j: usize| ((k as f64 * 12.9898 + j as f64 * 78.233).sin() * 43758.5453).fract() as f32;
        let mut buf = ReplayBuffer::new(obs_dim, act_dim, 4 * n);
        for k in 0..4 * n {
            let obs: Vec<f32> = (0..obs_dim).map(|j| value(k, j)).collect();
            let next_obs: Vec<f32> = (0..obs_dim).map(|j| value(k, j + 7)).collect();
            let action: Vec<f32> = (0..act_dim).map(|j| 0.9 * value(k, j + 17)).collect();
            buf.push(&Transition {
                obs: &obs,
                action: &action,
                reward: value(k, 29),
                next_obs: &next_obs,
                done: k % 5 == 0,
                demonstration: k % 3 == 0,
            });
        }
        buf.sample(n, &mut sampler(4))
    }

    #[test]
    fn a_batch_is_sent_as_its_columns() {
        let _guard = torch_lock();
        let sac = Sac::new(SacConfig::default(), 5, 3, Device::Cpu);
        let batch = random_batch(5, 3, 7);
        assert!(batch.dones.contains(&1.0) && batch.dones.contains(&0.0));
        let tensors = sac.batch_tensors(&batch);
        let column = |t: &Tensor, width: i64| {
            assert_eq!(t.size(), [7, width]);
            Vec::<f32>::try_from(t.reshape([-1])).unwrap()
        };
        assert_eq!(column(&tensors.obs, 5), batch.obs);
        assert_eq!(column(&tensors.actions, 3), batch.actions);
        assert_eq!(column(&tensors.rewards, 1), batch.rewards);
        assert_eq!(column(&tensors.next_obs, 5), batch.next_obs);
        assert_eq!(column(&tensors.demonstrations, 1), batch.demonstrations);
        let gamma = sac.config.discount as f32;
        let bootstrap: Vec<f32> = batch
            .dones
            .iter()
            .map(|&d| if d == 1.0 { 0.0 } else { gamma })
            .collect();
        assert_eq!(column(&tensors.continuation, 1), bootstrap);
        assert_eq!(tensors.any_demonstration, batch.demonstrations.contains(&1.0));
    }

    fn assert_same_gradients(manual: &[Tensor], reference: &[Tensor], what: &str) {
        assert_eq!(manual.len(), reference.len(), "{what}");
        for (k, (m, r)) in manual.iter().zip(reference).enumerate() {
            assert_eq!(m.size(), r.size(), "{what} #{k}");
            let scale = r.abs().max().double_value(&[]).max(1e-6);
            let error = (m - r).abs().max().double_value(&[]);
            assert!(error <= 2e-5 * scale, "{what} #{k}: off by {error} at scale {scale}");
        }
    }

    /// The hand-written gradients of an update equal autograd's on the losses as written (the
    /// soft Bellman regression, the soft actor loss alone and with the normalised cloning term
    /// of a non-quadratic error), with two of the three log-standard deviations outside their
    /// clamp and unequal hidden widths, so a transposed or misrouted term shows.
    #[test]
    fn hand_written_gradients_equal_autograd_on_the_losses() {
        let _torch = torch_lock();
        for behaviour_cloning in [0.0, 2.5] {
            tch::manual_seed(3);
            let config = SacConfig {
                hidden: vec![24, 16],
                batch_size: 32,
                behaviour_cloning,
                initial_log_temperature: -1.0,
                ..SacConfig::default()
            };
            let cloning = crate::cloning::ThrustError {
                log_throttle: true,
                components: 3,
            };
            let sac = Sac::with_cloning_loss(config, 5, 3, Device::Cpu, Box::new(cloning));
            tch::no_grad(|| {
                let log_std_bias = &sac.actor_store.variables()["actor.log_std.bias"];
                log_std_bias
                    .shallow_clone()
                    .copy_(&Tensor::from_slice(&[2.5f32, 0.0, -21.0]));
            });
            let batch = sac.batch_tensors(&random_batch(5, 3, 32));
            let temperature = sac.log_temperature.exp().detach();

            tch::manual_seed(5);
            let critic = tch::no_grad(|| sac.critic_gradients(&batch, &temperature));
            tch::manual_seed(5);
            let target = tch::no_grad(|| {
                let next = sac.actor.sample(&batch.next_obs);
                let q_next = sac.targets.min_q(&batch.next_obs, &next.action);
                soft_bellman_target(
                    &batch.rewards,
                    &batch.continuation,
                    &q_next,
                    &next.log_prob,
                    &temperature,
                )
            });
            let q = sac.critics.forward(&batch.obs, &batch.actions);
            let loss = (q - target).square().mean(Kind::Float) * 2.0;
            assert!((loss.double_value(&[]) - critic.loss.double_value(&[])).abs() < 1e-5);
            let reference = Tensor::run_backward(&[&loss], &sac.critics.parameters(), false, false);
            assert_same_gradients(&critic.grads, &reference, "critic");

            // Shift the second critic's output bias by the mean gap between the two on the
            // actor's sample, so that min picks each critic in some of the rows (the median
            // would tie one row, where autograd's amin splits the gradient).
            tch::manual_seed(6);
            tch::no_grad(|| {
                let sample = sac.actor.sample(&batch.obs);
                let q = sac.critics.forward(&batch.obs, &sample.action);
                let gap = (q.get(0) - q.get(1)).mean(Kind::Float);
                let output_bias = &sac.critic_store.variables()["critic.b2"];
                let _ = output_bias.get(1).g_add_(&gap);
            });
            tch::manual_seed(6);
            let actor = tch::no_grad(|| sac.actor_gradients(&batch, &temperature));
            tch::manual_seed(6);
            let sample = sac.actor.sample(&batch.obs);
            let both = sac.critics.forward(&batch.obs, &sample.action);
            let q_pi = both.amin(0, false);
            // Each critic is the smaller in some rows, so both routes of min's gradient are used.
            let first_smaller = both.get(0).lt_tensor(&both.get(1)).sum(Kind::Int64).int64_value(&[]);
            assert!(0 < first_smaller && first_smaller < 32, "{first_smaller} of 32 rows");
            let soft_loss = (&temperature * &sample.log_prob - &q_pi).mean(Kind::Float);
            let loss = if behaviour_cloning > 0.0 {
                let error = cloning.error(&sample.mean_action(), &batch.actions);
                let demos = &batch.demonstrations;
                let bc = (error * demos).sum(Kind::Float) / demos.sum(Kind::Float).clamp_min(1.0);
                assert!((bc.double_value(&[]) - actor.cloning_loss).abs() < 1e-5);
                &soft_loss / q_pi.abs().mean(Kind::Float).detach().clamp_min(1e-6) + bc * behaviour_cloning
            } else {
                soft_loss.shallow_clone()
            };
            assert!((soft_loss.double_value(&[]) - actor.soft_loss.double_value(&[])).abs() < 1e-5);
            let reference = Tensor::run_backward(&[&loss], &sac.actor.parameters(), false, false);
            // The clamped log-standard deviations pass nothing back.
            let log_std_bias_grad = &reference[reference.len() - 1];
            assert_eq!(log_std_bias_grad.double_value(&[0]), 0.0);
            assert_ne!(log_std_bias_grad.double_value(&[1]), 0.0);
            assert_same_gradients(&actor.grads, &reference, "actor");
        }
    }

    #[test]
    fn critic_learns_the_reward_and_actor_finds_the_bandit_optimum() {
        let _torch = torch_lock();
        let mut sac = tiny(SacConfig {
            learning_rate: 3e-3,
            ..SacConfig::default()
        });
        let buf = bandit_buffer(256);
        let mut rng = sampler(1);
        for _ in 0..1500 {
            sac.update(&buf.sample(64, &mut rng));
        }
        // Terminal transitions: the soft target is the reward itself, so Q(s, a) -> -(a - 0.5)^2.
        let actions = [-0.8f32, -0.2, 0.5, 0.9];
        let q = sac.q_value(&[1.0; 4], &actions, 4);
        for (a, q) in actions.iter().zip(&q) {
            let expected = -(a - 0.5) * (a - 0.5);
            assert!((q - expected).abs() < 0.05, "Q({a}) = {q}, expected {expected}");
        }
        let best = sac.act(&[1.0], 1)[0];
        assert!((best - 0.5).abs() < 0.1, "deterministic action {best}");
    }

    #[test]
    fn cloning_updates_fit_the_demonstrations_from_a_shipped_actor_and_touch_no_critic() {
        let _torch = torch_lock();
        // Demonstrations of a = 0.5 on the bandit's observation.
        let mut demos = ReplayBuffer::new(1, 1, 64);
        for _ in 0..64 {
            demos.push(&Transition {
                obs: &[1.0],
                action: &[0.5],
                reward: 0.0,
                next_obs: &[1.0],
                done: true,
                demonstration: true,
            });
        }
        let config = SacConfig {
            learning_rate: 3e-3,
            actor_averaging: 0.01,
            ..SacConfig::default()
        };
        // A "shipped" actor: another learner's flown actor, written alone.
        let mut shipped = tiny(config.clone());
        let mut rng = sampler(3);
        for _ in 0..20 {
            shipped.update(&bandit_buffer(64).sample(64, &mut rng));
        }
        let dir = std::env::temp_dir().join(format!("lowthrust-actor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("actor.safetensors");
        shipped.save_flown_actor(&file).unwrap();

        tch::manual_seed(99);
        let mut sac = Sac::new(
            SacConfig {
                hidden: vec![32, 32],
                batch_size: 64,
                ..config
            },
            1,
            1,
            Device::Cpu,
        );
        sac.start_from_actor(&file).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // Both the flown (averaged) actor and the online one start from the file.
        assert_eq!(sac.act(&[1.0], 1), shipped.act(&[1.0], 1));
        let online = |s: &Sac| tch::no_grad(|| s.actor.deterministic(&Tensor::from_slice(&[1.0f32]).view([1, 1])));
        assert_eq!(online(&sac).double_value(&[0, 0]) as f32, shipped.act(&[1.0], 1)[0]);

        let q_before = sac.q_value(&[1.0], &[0.2], 1);
        let first = sac.cloning_update(&demos.sample(64, &mut rng));
        let mut last = first;
        for _ in 0..300 {
            last = sac.cloning_update(&demos.sample(64, &mut rng));
        }
        assert_eq!(sac.updates, 301);
        assert!(last < 0.01 * first.max(1e-4), "cloning error {first} -> {last}");
        assert!(
            (sac.act(&[1.0], 1)[0] - 0.5).abs() < 0.05,
            "flown action {:?}",
            sac.act(&[1.0], 1)
        );
        assert_eq!(sac.q_value(&[1.0], &[0.2], 1), q_before, "the critics are untouched");
    }

    #[test]
    fn a_narrower_actor_is_widened_without_changing_its_output_and_its_added_units_learn() {
        let _torch = torch_lock();
        let config = SacConfig {
            learning_rate: 3e-3,
            actor_averaging: 0.01,
            batch_size: 64,
            ..SacConfig::default()
        };
        let learner = |hidden: Vec<usize>, obs_dim: usize, seed: i64| {
            tch::manual_seed(seed);
            Sac::new(
                SacConfig {
                    hidden,
                    ..config.clone()
                },
                obs_dim,
                2,
                Device::Cpu,
            )
        };
        let dir = std::env::temp_dir().join(format!("lowthrust-widen-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = |name: &str, sac: &Sac| {
            let path = dir.join(name);
            sac.save_flown_actor(&path).unwrap();
            path
        };
        let narrow = learner(vec![8, 6], 3, 5);
        let narrow_file = file("narrow.safetensors", &narrow);
        let deeper_file = file("deeper.safetensors", &learner(vec![8, 6, 4], 3, 5));
        let other_features = file("features.safetensors", &learner(vec![8, 6], 4, 5));

        let mut wide = learner(vec![16, 12], 3, 9);
        assert!(wide.start_from_actor(&deeper_file).is_err(), "another depth");
        assert!(wide.start_from_actor(&other_features).is_err(), "other features");
        assert!(
            learner(vec![4, 6], 3, 9).start_from_actor(&narrow_file).is_err(),
            "a wider file"
        );
        // A tensor of another rank: refused, not a panic.
        let flattened: Vec<(String, Tensor)> = narrow
            .actor_store
            .variables()
            .into_iter()
            .map(|(n, t)| {
                if n == "actor.l0.weight" {
                    (n, t.view([-1]))
                } else {
                    (n, t)
                }
            })
            .collect();
        let flattened_file = dir.join("flattened.safetensors");
        write_checked_safetensors(&flattened, &BTreeMap::new(), &flattened_file).unwrap();
        assert!(wide.start_from_actor(&flattened_file).is_err(), "another rank");
        assert_eq!(wide.start_from_actor(&narrow_file).unwrap(), vec![8, 6]);
        std::fs::remove_dir_all(&dir).unwrap();

        // The same function on observations it never saw, flown (averaged) and online alike.
        let obs: Vec<f32> = (0..60).map(|i| ((i * 37 % 23) as f32 / 23.0 - 0.5) * 4.0).collect();
        let (before, after) = (narrow.act(&obs, 20), wide.act(&obs, 20));
        let online = tch::no_grad(|| wide.actor.deterministic(&Tensor::from_slice(&obs).view([20, 3])));
        let online = Vec::<f32>::try_from(online.view([-1])).unwrap();
        for ((b, a), o) in before.iter().zip(&after).zip(&online) {
            assert!((b - a).abs() < 1e-6 && (a - o).abs() < 1e-6, "{b} {a} {o}");
        }
        // The added units' head weights start at zero and leave it once trained.
        let added_head_weight = |sac: &Sac| {
            let w = &sac.actor_store.variables()["actor.mean.weight"];
            w.narrow(1, 6, 6).abs().sum(Kind::Float).double_value(&[])
        };
        assert_eq!(added_head_weight(&wide), 0.0);
        let mut demos = ReplayBuffer::new(3, 2, 256);
        for k in 0..256 {
            let o = [
                (k % 7) as f32 / 3.5 - 1.0,
                (k % 11) as f32 / 5.5 - 1.0,
                (k % 5) as f32 / 2.5 - 1.0,
            ];
            demos.push(&Transition {
                obs: &o,
                action: &[(o[0] * o[1]).tanh(), (o[2] - o[0]).sin() * 0.8],
                reward: 0.0,
                next_obs: &o,
                done: true,
                demonstration: true,
            });
        }
        let mut rng = sampler(4);
        for _ in 0..50 {
            wide.cloning_update(&demos.sample(64, &mut rng));
        }
        assert!(added_head_weight(&wide) > 1e-3, "{}", added_head_weight(&wide));
    }

    #[test]
    fn soft_target_adds_the_entropy_bonus_and_stops_at_terminal_states() {
        let t = |v: &[f32]| Tensor::from_slice(v).view([-1, 1]);
        let y = soft_bellman_target(
            &t(&[1.0, 1.0, -0.5]),
            &t(&continuation(&[0.0, 1.0, 0.0], 0.9)),
            &t(&[2.0, 2.0, -3.0]),
            &t(&[-0.5, -0.5, 1.5]),
            &Tensor::from_slice(&[0.1f32]),
        );
        // 1 + 0.9 (2 + 0.1 * 0.5); terminal: the reward alone; -0.5 + 0.9 (-3 - 0.1 * 1.5).
        let expected = [2.845f32, 1.0, -0.5 + 0.9 * (-3.0 - 0.15)];
        let got = Vec::<f32>::try_from(y.view([-1])).unwrap();
        for (g, e) in got.iter().zip(expected) {
            assert!((g - e).abs() < 1e-6, "{got:?} vs {expected:?}");
        }
    }

    #[test]
    fn temperature_moves_toward_the_entropy_target() {
        let _torch = torch_lock();
        let buf = bandit_buffer(64);
        for (target, should_rise) in [(5.0, true), (-50.0, false)] {
            let mut sac = tiny(SacConfig {
                target_entropy: Some(target),
                ..SacConfig::default()
            });
            let before = sac.temperature();
            let mut rng = sampler(2);
            for _ in 0..5 {
                sac.update(&buf.sample(64, &mut rng));
            }
            let after = sac.temperature();
            assert_eq!(after > before, should_rise, "target {target}: {before} -> {after}");
        }
        // An unreachable entropy target raises alpha at every update; a cap stops it there and
        // leaves the lowering direction alone.
        let mut capped = tiny(SacConfig {
            target_entropy: Some(5.0),
            initial_log_temperature: -0.1,
            max_log_temperature: Some(0.0),
            learning_rate: 1e-2,
            ..SacConfig::default()
        });
        let mut rng = sampler(2);
        for _ in 0..50 {
            capped.update(&buf.sample(64, &mut rng));
        }
        assert_eq!(capped.temperature(), 1.0, "alpha rose to the cap and stays there");
        capped.target_entropy = -50.0;
        capped.update(&buf.sample(64, &mut rng));
        assert!(capped.temperature() < 1.0);
    }

    #[test]
    fn targets_are_polyak_averages_of_the_online_critics() {
        let _torch = torch_lock();
        let mut sac = tiny(SacConfig {
            target_smoothing: 0.1,
            ..SacConfig::default()
        });
        let snapshot = |sac: &Sac| -> Vec<(Tensor, Tensor)> {
            sac.target_pairs().iter().map(|(t, s)| (t.copy(), s.copy())).collect()
        };
        let initial = snapshot(&sac);
        assert_eq!(initial.len(), sac.critic_store.trainable_variables().len());
        for (t, s) in &initial {
            assert_eq!(t.size(), s.size());
            assert!(
                t.allclose(s, 0.0, 0.0, false),
                "targets start equal to the online critics"
            );
        }
        let buf = bandit_buffer(64);
        sac.update(&buf.sample(64, &mut sampler(3)));
        for ((t_old, _), (t_new, s_new)) in initial.iter().zip(snapshot(&sac)) {
            let expected = t_old * 0.9 + &s_new * 0.1;
            assert!(t_new.allclose(&expected, 1e-6, 1e-7, false));
        }
    }

    #[test]
    fn the_averaged_actor_trails_the_online_one_by_name_and_is_what_flies() {
        let _torch = torch_lock();
        let tau = 0.25;
        let mut sac = tiny(SacConfig {
            actor_averaging: tau,
            learning_rate: 1e-2,
            ..SacConfig::default()
        });
        // By name, independently of the flat buffers the averaging runs on.
        let pairs = |sac: &Sac| -> Vec<(String, Tensor, Tensor)> {
            let online = sac.actor_store.variables();
            let average = sac.average.as_ref().expect("averaging is on").store.variables();
            let mut names: Vec<_> = online.keys().cloned().collect();
            names.sort();
            assert_eq!(names.len(), average.len());
            names
                .into_iter()
                .map(|n| {
                    let (a, o) = (average[&n].copy(), online[&n].copy());
                    (n, a, o)
                })
                .collect()
        };
        for (name, a, o) in pairs(&sac) {
            assert!(
                a.allclose(&o, 0.0, 0.0, false),
                "{name}: the average starts at the actor"
            );
        }
        let before = pairs(&sac);
        let buf = bandit_buffer(64);
        let mut rng = sampler(6);
        for _ in 0..3 {
            let previous = pairs(&sac);
            // A running mean first (1/2, 1/3, ...), tau once that falls below it.
            let weight = tau.max(1.0 / (sac.updates as f64 + 2.0));
            sac.update(&buf.sample(64, &mut rng));
            for ((name, a_old, _), (_, a_new, o_new)) in previous.iter().zip(pairs(&sac)) {
                let expected = a_old * (1.0 - weight) + &o_new * weight;
                assert!(a_new.allclose(&expected, 1e-6, 1e-7, false), "{name}");
            }
        }
        // The online actor moved away from the average, and the flown actor is the average:
        // deterministic actions and the exported weights both come from it.
        let obs = Tensor::from_slice(&[0.3f32, -0.7, 1.0]).view([3, 1]);
        let averaged = sac.average.as_ref().unwrap().actor.deterministic(&obs);
        let online = sac.actor.deterministic(&obs);
        assert!(!averaged.allclose(&online, 1e-6, 1e-6, false));
        let flown = Tensor::from_slice(&sac.act(&[0.3, -0.7, 1.0], 3)).view([3, 1]);
        assert!(flown.allclose(&averaged, 0.0, 0.0, false));
        let exported = sac.actor_weights();
        for (name, a, o) in pairs(&sac) {
            let (_, data) = &exported[name.trim_start_matches("actor.")];
            assert_eq!(data, &Vec::<f32>::try_from(a.view([-1])).unwrap(), "{name}");
            let unchanged = before.iter().find(|(n, ..)| *n == name).unwrap();
            assert!(
                !o.allclose(&unchanged.2, 0.0, 0.0, false),
                "{name}: the online actor trains"
            );
        }
        // A checkpoint carries the average.
        let dir = std::env::temp_dir().join(format!("sac-average-{}", std::process::id()));
        let path = dir.join("agent.safetensors");
        sac.save(&path).unwrap();
        let mut restored = tiny(SacConfig {
            actor_averaging: tau,
            learning_rate: 1e-2,
            ..SacConfig::default()
        });
        restored.load(&path).unwrap();
        assert_eq!(restored.act(&[0.3, -0.7, 1.0], 3), sac.act(&[0.3, -0.7, 1.0], 3));
        // ... and keeps averaging in place after the load: one more identical update on both.
        let batch = buf.sample(64, &mut sampler(8));
        tch::manual_seed(5);
        sac.update(&batch);
        tch::manual_seed(5);
        restored.update(&batch);
        assert_eq!(restored.act(&[0.3, -0.7, 1.0], 3), sac.act(&[0.3, -0.7, 1.0], 3));
        // Either way round, averaging on one side only is refused.
        let plain = tiny(SacConfig::default());
        assert!(matches!(
            tiny(SacConfig::default()).load(&path),
            Err(CheckpointError::Mismatch(_))
        ));
        let mut averaging = tiny(SacConfig {
            actor_averaging: tau,
            ..SacConfig::default()
        });
        let plain_path = dir.join("plain.safetensors");
        plain.save(&plain_path).unwrap();
        assert!(matches!(averaging.load(&plain_path), Err(CheckpointError::Mismatch(_))));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn checkpoint_round_trip_restores_the_policy_and_refuses_mismatches() {
        let _torch = torch_lock();
        let dir = std::env::temp_dir().join(format!("sac-ckpt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("agent.safetensors");
        let mut sac = tiny(SacConfig::default());
        let buf = bandit_buffer(64);
        let mut rng = sampler(4);
        for _ in 0..3 {
            sac.update(&buf.sample(64, &mut rng));
        }
        sac.save(&path).unwrap();
        let obs = [0.3f32, -0.7, 1.0];
        let mut other = tiny(SacConfig {
            initial_log_temperature: 1.0,
            ..SacConfig::default()
        });
        assert_ne!(other.act(&obs, 3), sac.act(&obs, 3));
        other.load(&path).unwrap();
        assert_eq!(other.act(&obs, 3), sac.act(&obs, 3));
        assert_eq!(other.temperature(), sac.temperature());
        assert_eq!(other.updates, 3);
        // Resumed training continues identically (same batches, same optimiser moments).
        tch::manual_seed(5);
        let s1 = sac.update(&buf.sample(64, &mut sampler(9)));
        tch::manual_seed(5);
        let s2 = other.update(&buf.sample(64, &mut sampler(9)));
        assert_eq!(s1, s2);

        let mut wider = Sac::new(
            SacConfig {
                hidden: vec![48, 32],
                ..SacConfig::default()
            },
            1,
            1,
            Device::Cpu,
        );
        assert!(matches!(wider.load(&path), Err(CheckpointError::Mismatch(_))));
        // Labels: a labelled checkpoint loads into a learner of the same label or none, and is
        // refused, both values named, by a learner labelled otherwise; the tensors stay.
        let labelled = dir.join("labelled.safetensors");
        sac.labels = BTreeMap::from([("family".to_string(), "venus".to_string())]);
        sac.save(&labelled).unwrap();
        let (_, labels) = read_labelled_safetensors(&labelled).unwrap();
        assert_eq!(labels, sac.labels);
        // The same labelled state is the same bytes, however many labels (a hash map's order
        // would differ from one write to the next).
        let mut many = sac.labels.clone();
        many.extend((0..6).map(|k| (format!("label{k}"), format!("value{k}"))));
        let (first, second) = (dir.join("first.safetensors"), dir.join("second.safetensors"));
        for path in [&first, &second] {
            write_checked_safetensors(&sac.named_state(), &many, path).unwrap();
        }
        assert_eq!(std::fs::read(&first).unwrap(), std::fs::read(&second).unwrap());
        assert_eq!(read_labelled_safetensors(&first).unwrap().1, many);
        for path in [&first, &second] {
            std::fs::remove_file(path).unwrap();
        }
        other.labels = sac.labels.clone();
        other.load(&labelled).unwrap();
        other.labels = BTreeMap::from([("family".to_string(), "mars".to_string())]);
        let before = other.act(&obs, 3);
        match other.load(&labelled) {
            Err(CheckpointError::Mismatch(why)) => {
                assert!(why.contains("venus") && why.contains("mars"), "{why}")
            }
            result => panic!("{result:?}"),
        }
        assert_eq!(other.act(&obs, 3), before);
        other.labels.clear();
        other.load(&labelled).unwrap();
        std::fs::remove_file(&labelled).unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        bytes.truncate(bytes.len() / 2);
        let broken = dir.join("broken.safetensors");
        std::fs::write(&broken, &bytes).unwrap();
        assert!(matches!(other.load(&broken), Err(CheckpointError::Format(_))));
        assert!(matches!(
            other.load(&dir.join("absent.safetensors")),
            Err(CheckpointError::Io(_))
        ));
        // A write that fails (here: the folder is a file) is an I/O error naming the file, not
        // a format error, and leaves nothing behind.
        let not_a_folder = dir.join("file");
        std::fs::write(&not_a_folder, b"x").unwrap();
        let target = not_a_folder.join("checkpoint.safetensors");
        match sac.save(&target) {
            Err(CheckpointError::Io(e)) => assert!(e.to_string().contains(&*target.to_string_lossy()), "{e}"),
            other => panic!("a failed write reported as {other:?}"),
        }
        let mut names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        assert_eq!(names, ["agent.safetensors", "broken.safetensors", "file"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
