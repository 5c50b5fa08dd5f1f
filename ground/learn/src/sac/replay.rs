//! FIFO experience replay: fixed capacity, the oldest transition is overwritten first. Stored as
//! flat f32 arrays so a batch becomes a tensor with one copy, and the whole buffer checkpoints as
//! one checksummed file.

use rand_chacha::ChaCha8Rng;
use rand_core::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// One transition (s, a, r, s', done); `demonstration` marks tuples from optimal trajectories so
/// the behaviour-cloning term applies to them only.
#[derive(Debug, Clone, PartialEq)]
pub struct Transition<'a> {
    /// Observation s, `obs_dim` features.
    pub obs: &'a [f32],
    /// Action a, `act_dim` components in [-1, 1].
    pub action: &'a [f32],
    /// Reward of the step.
    pub reward: f32,
    /// Observation s' after the step.
    pub next_obs: &'a [f32],
    /// s' is terminal: nothing is bootstrapped past it.
    pub done: bool,
    /// The tuple comes from a demonstration or a relabel, not from the agent's own flight.
    pub demonstration: bool,
}

/// The replay buffer: [`Transition`]s column by column in flat f32 arrays, up to a fixed
/// capacity; serialisable, so a checkpoint carries it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ReplayBuffer {
    obs_dim: usize,
    act_dim: usize,
    capacity: usize,
    /// Index the next transition is written to.
    cursor: usize,
    len: usize,
    obs: Vec<f32>,
    actions: Vec<f32>,
    rewards: Vec<f32>,
    next_obs: Vec<f32>,
    dones: Vec<f32>,
    demonstrations: Vec<f32>,
}

/// A sampled mini-batch, row-major `[batch, dim]`.
#[derive(Debug, Clone, Default)]
pub struct Batch {
    /// Rows (transitions) in the batch.
    pub size: usize,
    /// Observations, `[size, obs_dim]`.
    pub obs: Vec<f32>,
    /// Actions, `[size, act_dim]`.
    pub actions: Vec<f32>,
    /// Rewards, `[size]`.
    pub rewards: Vec<f32>,
    /// Next observations, `[size, obs_dim]`.
    pub next_obs: Vec<f32>,
    /// 1 where s' is terminal, else 0, `[size]`.
    pub dones: Vec<f32>,
    /// 1 for demonstration tuples, else 0, `[size]`.
    pub demonstrations: Vec<f32>,
}

impl ReplayBuffer {
    /// An empty buffer of `capacity` transitions of these dimensions; panics on a zero capacity.
    pub fn new(obs_dim: usize, act_dim: usize, capacity: usize) -> Self {
        assert!(capacity > 0, "replay capacity must be positive");
        Self {
            obs_dim,
            act_dim,
            capacity,
            cursor: 0,
            len: 0,
            obs: Vec::new(),
            actions: Vec::new(),
            rewards: Vec::new(),
            next_obs: Vec::new(),
            dones: Vec::new(),
            demonstrations: Vec::new(),
        }
    }

    /// Transitions stored (at most the capacity).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no transition is stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The most transitions it holds before overwriting the oldest.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Observation features per transition.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Action components per transition.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    /// Number of stored transitions that came from demonstrations.
    pub fn demonstration_count(&self) -> usize {
        self.demonstrations[..self.len].iter().filter(|&&d| d > 0.5).count()
    }

    /// Appends a transition, overwriting the oldest once full. Panics on a dimension mismatch,
    /// which is a programming error (the environment fixes the dimensions).
    pub fn push(&mut self, t: &Transition) {
        assert_eq!(t.obs.len(), self.obs_dim, "observation length");
        assert_eq!(t.next_obs.len(), self.obs_dim, "next observation length");
        assert_eq!(t.action.len(), self.act_dim, "action length");
        let i = self.cursor;
        if self.len < self.capacity && i == self.rewards.len() {
            self.obs.extend_from_slice(t.obs);
            self.actions.extend_from_slice(t.action);
            self.rewards.push(t.reward);
            self.next_obs.extend_from_slice(t.next_obs);
            self.dones.push(f32::from(u8::from(t.done)));
            self.demonstrations.push(f32::from(u8::from(t.demonstration)));
        } else {
            self.obs[i * self.obs_dim..(i + 1) * self.obs_dim].copy_from_slice(t.obs);
            self.actions[i * self.act_dim..(i + 1) * self.act_dim].copy_from_slice(t.action);
            self.rewards[i] = t.reward;
            self.next_obs[i * self.obs_dim..(i + 1) * self.obs_dim].copy_from_slice(t.next_obs);
            self.dones[i] = f32::from(u8::from(t.done));
            self.demonstrations[i] = f32::from(u8::from(t.demonstration));
        }
        self.cursor = (i + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
    }

    /// The transition stored at slot `i` (0 <= i < len), in storage order.
    pub fn get(&self, i: usize) -> Transition<'_> {
        assert!(i < self.len, "replay index out of range");
        Transition {
            obs: &self.obs[i * self.obs_dim..(i + 1) * self.obs_dim],
            action: &self.actions[i * self.act_dim..(i + 1) * self.act_dim],
            reward: self.rewards[i],
            next_obs: &self.next_obs[i * self.obs_dim..(i + 1) * self.obs_dim],
            done: self.dones[i] > 0.5,
            demonstration: self.demonstrations[i] > 0.5,
        }
    }

    /// The `back`-th newest transition (1: the last pushed), if the buffer holds that many.
    pub fn newest(&self, back: usize) -> Option<Transition<'_>> {
        (back >= 1 && back <= self.len).then(|| self.get((self.cursor + self.capacity - back) % self.capacity))
    }

    /// Appends every transition of `other` in its storage order (FIFO eviction as for `push`).
    pub fn extend_from(&mut self, other: &ReplayBuffer) {
        for i in 0..other.len() {
            self.push(&other.get(i));
        }
    }

    /// Uniform sample with replacement.
    pub fn sample(&self, size: usize, rng: &mut ChaCha8Rng) -> Batch {
        assert!(!self.is_empty(), "cannot sample an empty replay buffer");
        let mut b = Batch {
            size,
            obs: Vec::with_capacity(size * self.obs_dim),
            actions: Vec::with_capacity(size * self.act_dim),
            rewards: Vec::with_capacity(size),
            next_obs: Vec::with_capacity(size * self.obs_dim),
            dones: Vec::with_capacity(size),
            demonstrations: Vec::with_capacity(size),
        };
        for _ in 0..size {
            // Modulo bias is below 1e-13 for any capacity that fits in memory.
            let i = (rng.next_u64() % self.len as u64) as usize;
            b.obs
                .extend_from_slice(&self.obs[i * self.obs_dim..(i + 1) * self.obs_dim]);
            b.actions
                .extend_from_slice(&self.actions[i * self.act_dim..(i + 1) * self.act_dim]);
            b.rewards.push(self.rewards[i]);
            b.next_obs
                .extend_from_slice(&self.next_obs[i * self.obs_dim..(i + 1) * self.obs_dim]);
            b.dones.push(self.dones[i]);
            b.demonstrations.push(self.demonstrations[i]);
        }
        b
    }
}

/// A seeded sampler stream (kept apart from the networks' RNG so a resume can restore both).
pub fn sampler(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(v: f32) -> ([f32; 2], [f32; 1], [f32; 2]) {
        ([v, v + 0.5], [v], [v + 1.0, v + 1.5])
    }

    #[test]
    fn fifo_overwrites_the_oldest_first() {
        let mut buf = ReplayBuffer::new(2, 1, 3);
        for k in 0..5 {
            let (o, a, n) = t(k as f32);
            buf.push(&Transition {
                obs: &o,
                action: &a,
                reward: k as f32,
                next_obs: &n,
                done: k == 4,
                demonstration: k < 2,
            });
        }
        assert_eq!(buf.len(), 3);
        // Slots hold 3, 4, 2 (0 and 1 were overwritten by 3 and 4, in that order).
        let rewards: Vec<f32> = (0..3).map(|i| buf.get(i).reward).collect();
        assert_eq!(rewards, vec![3.0, 4.0, 2.0]);
        assert!(buf.get(1).done && !buf.get(0).done);
        assert_eq!(buf.demonstration_count(), 0);
        let (o, _, n) = t(4.0);
        assert_eq!(buf.get(1).obs, &o);
        assert_eq!(buf.get(1).next_obs, &n);
    }

    #[test]
    fn samples_are_uniform_and_rows_stay_together() {
        let mut buf = ReplayBuffer::new(2, 1, 10);
        for k in 0..10 {
            let (o, a, n) = t(k as f32);
            buf.push(&Transition {
                obs: &o,
                action: &a,
                reward: k as f32,
                next_obs: &n,
                done: false,
                demonstration: false,
            });
        }
        let mut rng = sampler(3);
        let mut counts = [0usize; 10];
        let b = buf.sample(20_000, &mut rng);
        for j in 0..b.size {
            let k = b.rewards[j];
            counts[k as usize] += 1;
            assert_eq!(b.obs[2 * j], k);
            assert_eq!(b.actions[j], k);
            assert_eq!(b.next_obs[2 * j + 1], k + 1.5);
        }
        // Each slot expects 2000 draws, sd ~ 42: 6 sd bounds.
        for c in counts {
            assert!((1750..=2250).contains(&c), "{counts:?}");
        }
    }
}
