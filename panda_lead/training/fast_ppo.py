"""`FastPPO`: stable-baselines3's PPO with the same update in fewer Python-level operations.

At the repo's default (a 64x64 MLP, minibatches of 1,024, 10 epochs) SB3's update is bound by
Python and torch's per-operation overhead, not by arithmetic: each minibatch step is ~1 ms
of small operations (docs/performance.md, "Profile of one training iteration"). This subclass
keeps SB3's algorithm and changes only how it is driven:

- the rollout buffer's flat arrays become torch tensors once per update (SB3 copies each
  minibatch out of numpy: six fancy-index copies and six tensor constructions per step), and
  each epoch gathers them once in the permuted order, so a minibatch is a slice (a view);
- the policy's forward pass for the loss is SB3's `evaluate_actions` written out for the
  diagonal Gaussian: the same operations in the same order (torch's `Normal.log_prob` and
  `entropy`), without building a `torch.distributions.Normal` and validating its arguments
  per minibatch;
- the logged statistics stay on the tensor side and are read once per update (SB3 calls
  `.item()` four times per minibatch), giving the same logged values;
- Adam runs torch's multi-tensor ("foreach") implementation: one kernel per operation over all
  parameter tensors instead of a loop over them, the same arithmetic (bit-identical here, see
  the tests; half the optimiser's time).

The collection's forward pass (`FastActorCriticPolicy.forward`, once per env step) is written
out the same way: the network's layers as functional calls and the Gaussian's sample and
log-probability without a `Normal`, one `normal_()` draw as `Normal.rsample` makes it.

What stays exactly SB3's: the losses, the minibatches (one `np.random.permutation` per epoch,
drawn from numpy's global stream as `RolloutBuffer.get` draws it), the number of gradient
steps, gradient clipping, Adam, the KL early stop. tests/test_fast_ppo.py holds it to
`PPO.train()`: one update from the same buffer and weights gives bit-identical parameters.

Anything outside the default shape (discrete or non-Gaussian actions, gSDE, a clipped value
function, dict observations, a custom rollout buffer) runs SB3's own `train()`. Deleting this
file and constructing `PPO` instead (`--no-fast-update`) is the whole rollback.

One addition, off by default (issue 36): CAPS's smoothness regularisers (Mysore et al., "Regularizing
Action Policies for Smooth Control with Reinforcement Learning", ICRA 2021) on the policy's mean
action, added to PPO's loss: temporal, ``caps_temporal`` x the mean squared change of the mean
action between an observation and the next one of the same episode in the rollout; spatial,
``caps_spatial`` x its mean squared change under Gaussian noise of ``caps_sigma`` on the
observation. Smoothness then shapes the policy's mapping, not its reward: a reward penalty on
the action's change (`w_action_change`) also pays the policy to be late. A third, beyond CAPS:
``caps_curvature`` x the mean squared second difference of the mean action over an observation,
the one before and the one after it in the same episode (the lead's acceleration, which is what
a Panda's joint acceleration limits see). For a sinusoid at f the squared second difference is
(2 sin(pi f dt))^2 times the squared first one: 0.06 at 4 Hz, 0.19 at 7 Hz (dt 10 ms), so
against the first difference it charges a 7 Hz ring 3x more than a 4 Hz swing of the lead.
``caps_curvature_delayed`` gives the curvature term another weight in the episodes with
latency, found by the observation's installation feature (its three delays).
"""

from __future__ import annotations

import math

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.distributions import (
    DiagGaussianDistribution,
    StateDependentNoiseDistribution,
)
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.torch_layers import FlattenExtractor, MlpExtractor
from stable_baselines3.common.utils import explained_variance
from torch.nn import functional as F

_FLAT = ("observations", "actions", "values", "log_probs", "advantages", "returns")
_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))  # the constant torch's Normal.log_prob uses
_HALF_LOG_2PI_E = 0.5 + 0.5 * math.log(2 * math.pi)  # and Normal.entropy's


def _run_layers(layers: th.nn.Module, x: th.Tensor) -> th.Tensor:
    """An nn.Sequential of Linear and Tanh layers as the functional calls their forward makes
    (F.linear, torch.tanh), without nn.Module's per-call machinery; any other layer as itself."""
    for layer in layers:
        if type(layer) is th.nn.Linear:
            x = F.linear(x, layer.weight, layer.bias)
        elif type(layer) is th.nn.Tanh:
            x = th.tanh(x)
        else:
            x = layer(x)
    return x


class FastActorCriticPolicy(ActorCriticPolicy):
    """SB3's MlpPolicy; `forward` (what PPO's collection calls once per step) is the same
    computation for a diagonal Gaussian without the Distribution objects: SB3's forward takes
    ~600 us for 32 observations of which the network is ~250 (docs/performance.md). Same
    operations, same single draw from torch's stream (Normal.rsample's ``normal_``), so the
    actions, values and log-probabilities are bit-identical (tests/test_fast_ppo.py)."""

    def _written_out(self) -> bool:
        """Whether forward's written-out path fits this policy (decided once: it is built)."""
        if not hasattr(self, "_fits"):
            self._fits = (isinstance(self.action_dist, DiagGaussianDistribution)
                          and not self.use_sde and self.share_features_extractor
                          and isinstance(self.observation_space, spaces.Box)
                          and type(self.features_extractor) is FlattenExtractor
                          and type(self.mlp_extractor) is MlpExtractor)
        return self._fits

    def forward(self, obs: th.Tensor, deterministic: bool = False):
        if not self._written_out():
            return super().forward(obs, deterministic)
        features = preprocess_obs(obs, self.observation_space,
                                  normalize_images=self.normalize_images).flatten(1)
        latent_pi = _run_layers(self.mlp_extractor.policy_net, features)
        latent_vf = _run_layers(self.mlp_extractor.value_net, features)
        values = F.linear(latent_vf, self.value_net.weight, self.value_net.bias)
        mean = F.linear(latent_pi, self.action_net.weight, self.action_net.bias)
        scale = th.ones_like(mean) * self.log_std.exp()  # DiagGaussian's action_std
        if deterministic:
            actions = mean
        else:  # Normal.rsample: loc + eps * scale, eps from one normal_() draw
            actions = mean + th.empty(mean.shape, dtype=mean.dtype,
                                      device=mean.device).normal_() * scale
        log_prob = (-((actions - mean) ** 2) / (2 * scale**2) - scale.log()
                    - _LOG_SQRT_2PI).sum(dim=1)
        return actions.reshape((-1, *self.action_space.shape)), values, log_prob


class FastPPO(PPO):
    """SB3's PPO; `train()` is the same update with fewer Python-level operations.
    ``update_threads``: torch threads during the update (the batched env is idle then), the
    process's own count restored after it; None: leave the count alone."""

    def __init__(self, *args, update_threads: int | None = None, caps_temporal: float = 0.0,
                 caps_spatial: float = 0.0, caps_sigma: float = 0.05,
                 caps_curvature: float = 0.0, caps_curvature_delayed: float | None = None,
                 delay_columns: tuple[int, ...] = (), plan_column: int | None = None,
                 **kwargs):
        self.update_threads = update_threads
        # the observation's plan_weight column (config.OBS_SCALE): the policy loss leaves out
        # the steps where the planner's hand holds the arm (weight 1: the action changes
        # nothing there, so its advantage says nothing about it); None: every step counts
        self.plan_column = plan_column
        self.caps_temporal, self.caps_spatial, self.caps_sigma = (caps_temporal, caps_spatial,
                                                                  caps_sigma)
        self.caps_curvature = caps_curvature
        # the weight in episodes with latency, found by the observation's delay columns
        if caps_curvature_delayed is not None and not delay_columns:
            raise ValueError("caps_curvature_delayed needs the observation's delay columns")
        self.caps_curvature_delayed, self.delay_columns = caps_curvature_delayed, delay_columns
        super().__init__(*args, **kwargs)

    @property
    def _caps(self) -> bool:
        return bool(self.caps_temporal or self.caps_spatial or self._curvature)

    @property
    def _curvature(self) -> bool:
        return bool(self.caps_curvature or self.caps_curvature_delayed)

    def _fast_path_applies(self) -> bool:
        p = self.policy
        return (isinstance(self.action_space, spaces.Box)
                and isinstance(self.observation_space, spaces.Box)
                and type(self.rollout_buffer) is RolloutBuffer
                and isinstance(p.action_dist, DiagGaussianDistribution
                               | StateDependentNoiseDistribution)
                and p.share_features_extractor and self.clip_range_vf is None)

    def _evaluate_actions(self, obs: th.Tensor, actions: th.Tensor, with_mean: bool = False):
        """SB3's ActorCriticPolicy.evaluate_actions for a diagonal Gaussian, operation for
        operation (DiagGaussianDistribution.proba_distribution, then torch's Normal.log_prob,
        the value head, Normal.entropy, in that order), minus the Distribution objects.
        ``with_mean``: also the mean action (for the CAPS terms)."""
        p = self.policy
        latent_pi, latent_vf = p.mlp_extractor(self._features(obs))
        mean_actions = p.action_net(latent_pi)
        if p.use_sde:  # gSDE: SB3's own distribution (its variance depends on latent_pi)
            dist = p.action_dist.proba_distribution(mean_actions, p.log_std, latent_pi)
            log_prob = dist.log_prob(actions)
            values, entropy = p.value_net(latent_vf), dist.entropy()
            return (values, log_prob, entropy, mean_actions) if with_mean else (
                values, log_prob, entropy)
        scale = th.ones_like(mean_actions) * p.log_std.exp()
        var = scale**2
        log_prob = (-((actions - mean_actions) ** 2) / (2 * var) - scale.log()
                    - _LOG_SQRT_2PI).sum(dim=1)
        values = p.value_net(latent_vf)
        entropy = (_HALF_LOG_2PI_E + th.log(scale)).sum(dim=1)
        if with_mean:
            return values, log_prob, entropy, mean_actions
        return values, log_prob, entropy

    def _features(self, obs: th.Tensor) -> th.Tensor:
        p = self.policy
        return p.features_extractor(preprocess_obs(obs, p.observation_space,
                                                   normalize_images=p.normalize_images))

    def _mean_action(self, obs: th.Tensor) -> th.Tensor:
        p = self.policy
        return p.action_net(p.mlp_extractor.forward_actor(self._features(obs)))

    def _neighbours(self, offset: int) -> tuple[th.Tensor, th.Tensor]:
        """For each flat buffer index, the index of the observation ``offset`` (+1 the next, -1
        the one before) steps away of the same env and episode, and whether there is one
        (inside the rollout, no reset between them: the later of the two is no episode's
        first). Flat index = env x n_steps + step, as swap_and_flatten lays them out."""
        buf = self.rollout_buffer
        n_steps, n_envs = buf.buffer_size, buf.n_envs
        n = n_steps * n_envs
        here = np.arange(n)
        other = np.clip(here + offset, 0, n - 1)
        step = np.tile(np.arange(n_steps), n_envs)
        starts = np.asarray(buf.episode_starts).swapaxes(0, 1).reshape(-1)
        inside = (step + offset >= 0) & (step + offset < n_steps)
        valid = inside & (starts[np.maximum(here, other)] == 0)
        return (th.as_tensor(other, device=self.device),
                th.as_tensor(valid, dtype=th.float32, device=self.device))

    def _delayed(self, observations: th.Tensor) -> th.Tensor:
        """Whether each observation's episode has latency: any of its installation delays
        (``delay_columns``) non-zero."""
        return observations[:, list(self.delay_columns)].abs().sum(dim=1) > 0

    def _caps_losses(self, mb: dict, mean: th.Tensor
                     ) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """CAPS's temporal and spatial terms and the curvature term for one minibatch: mean
        squared (first or second) differences of the mean action, per action dimension (zero
        when the weight is 0); last, the curvature term weighted per observation (the weight
        of its episode: caps_curvature, or caps_curvature_delayed where ``mb["delayed"]`` says
        the episode has latency), what the loss adds."""
        zero = mean.new_zeros(())
        temporal = spatial = curvature = weighted = zero
        has_next = mb["has_next"]
        if self.caps_temporal or self._curvature:
            following = self._mean_action(mb["next_observations"])
        if self.caps_temporal:
            diff = ((mean - following) ** 2).mean(dim=1)
            temporal = (diff * has_next).sum() / has_next.sum().clamp(min=1.0)
        if self.caps_spatial:
            noisy = mb["observations"] + self.caps_sigma * th.randn_like(mb["observations"])
            spatial = ((mean - self._mean_action(noisy)) ** 2).mean()
        if self._curvature:
            both = has_next * mb["has_previous"]
            second = following - 2 * mean + self._mean_action(mb["previous_observations"])
            per = (second ** 2).mean(dim=1) * both
            count = both.sum().clamp(min=1.0)
            curvature = per.sum() / count
            if self.caps_curvature_delayed is None:  # (the one weight: as it was written first)
                weighted = self.caps_curvature * curvature
            else:
                weight = th.where(mb["delayed"], self.caps_curvature_delayed, self.caps_curvature)
                weighted = (weight * per).sum() / count
        return temporal, spatial, curvature, weighted

    def _flat_tensors(self) -> dict[str, th.Tensor]:
        """The buffer's arrays flattened as RolloutBuffer.get flattens them (in place, once per
        rollout), as torch tensors sharing their memory."""
        buf = self.rollout_buffer
        if not buf.generator_ready:
            for name in _FLAT:
                buf.__dict__[name] = buf.swap_and_flatten(buf.__dict__[name])
            buf.generator_ready = True
        out = {name: th.as_tensor(buf.__dict__[name], device=self.device) for name in _FLAT}
        for name in _FLAT[2:]:  # (n, 1) -> (n,), as _get_samples' .flatten()
            out[name] = out[name].flatten()
        out["actions"] = out["actions"].float()  # as _get_samples' astype(float32)
        return out

    def train(self) -> None:
        if self.update_threads is None:
            return self._train()
        before = th.get_num_threads()
        th.set_num_threads(self.update_threads)
        try:
            return self._train()
        finally:
            th.set_num_threads(before)

    def _train(self) -> None:
        if not self._fast_path_applies():
            if self._caps or self.plan_column is not None:  # SB3's train() has neither
                raise ValueError("the CAPS terms and the planner's hand's mask need FastPPO's "
                                 "update (a diagonal Gaussian policy on Box spaces, no gSDE)")
            return super().train()
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        flat = self._flat_tensors()
        n = self.rollout_buffer.buffer_size * self.rollout_buffer.n_envs
        # SB3: batch_size None in get() means the whole buffer; PPO always passes its own.
        batch = self.batch_size
        pg_losses, value_losses, entropy_losses, clip_fractions = [], [], [], []
        caps_t, caps_s, caps_c = [], [], []
        if self._caps:
            successor, has_successor = self._neighbours(1)
            if self._curvature:
                predecessor, has_predecessor = self._neighbours(-1)
            if self.caps_curvature_delayed is not None:  # each observation's episode, once
                delayed = self._delayed(flat["observations"])
        params = list(self.policy.parameters())
        continue_training = True
        for epoch in range(self.n_epochs):
            approx_kl_divs = []
            # The one random draw of RolloutBuffer.get, from the same stream.
            order = th.as_tensor(np.random.permutation(n), device=self.device)
            epoch_data = {name: t[order] for name, t in flat.items()}
            if self._caps:
                epoch_data["next_observations"] = flat["observations"][successor[order]]
                epoch_data["has_next"] = has_successor[order]
                if self._curvature:
                    epoch_data["previous_observations"] = flat["observations"][
                        predecessor[order]]
                    epoch_data["has_previous"] = has_predecessor[order]
                if self.caps_curvature_delayed is not None:
                    epoch_data["delayed"] = delayed[order]
            for start in range(0, n, batch):
                mb = {name: t[start:start + batch] for name, t in epoch_data.items()}
                if self._caps:
                    values, log_prob, entropy, mean = self._evaluate_actions(
                        mb["observations"], mb["actions"], with_mean=True)
                else:
                    values, log_prob, entropy = self._evaluate_actions(mb["observations"],
                                                                       mb["actions"])
                values = values.flatten()
                advantages = mb["advantages"]
                ratio = th.exp(log_prob - mb["log_probs"])
                if self.plan_column is None:
                    policy_loss = self._clipped_policy_loss(advantages, ratio, clip_range)
                else:
                    policy_loss = self._led_policy_loss(
                        advantages, ratio, clip_range,
                        mb["observations"][:, self.plan_column] < 1.0)
                value_loss = F.mse_loss(mb["returns"], values)
                entropy_loss = -th.mean(entropy)
                loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * value_loss
                if self._caps:
                    temporal, spatial, curvature, weighted = self._caps_losses(mb, mean)
                    loss = (loss + self.caps_temporal * temporal + self.caps_spatial * spatial
                            + weighted)
                    caps_t.append(temporal.detach())
                    caps_s.append(spatial.detach())
                    caps_c.append(curvature.detach())
                with th.no_grad():
                    pg_losses.append(policy_loss.detach())
                    clip_fractions.append(th.mean((th.abs(ratio - 1) > clip_range).float()))
                    value_losses.append(value_loss.detach())
                    entropy_losses.append(entropy_loss.detach())
                    log_ratio = log_prob - mb["log_probs"]
                    approx_kl_divs.append(th.mean((th.exp(log_ratio) - 1) - log_ratio))
                # The early stop needs this minibatch's KL now; without it, read it at the end.
                if self.target_kl is not None and approx_kl_divs[-1].item() > 1.5 * self.target_kl:
                    continue_training = False
                    if self.verbose >= 1:
                        print(f"Early stopping at step {epoch} due to reaching max kl: "
                              f"{approx_kl_divs[-1].item():.2f}")
                    break
                self.policy.optimizer.zero_grad()
                loss.backward()
                th.nn.utils.clip_grad_norm_(params, self.max_grad_norm)
                self.policy.optimizer.step()
            self._n_updates += 1
            if not continue_training:
                break
        self._record(pg_losses, value_losses, entropy_losses, clip_fractions, approx_kl_divs,
                     loss, clip_range)
        if self._caps:
            self.logger.record("train/caps_temporal", float(th.stack(caps_t).mean()) if caps_t else 0.0)
            self.logger.record("train/caps_spatial", float(th.stack(caps_s).mean()) if caps_s else 0.0)
            if self._curvature:
                self.logger.record("train/caps_curvature", float(th.stack(caps_c).mean()))

    def _clipped_policy_loss(self, advantages: th.Tensor, ratio: th.Tensor,
                             clip_range: float) -> th.Tensor:
        """SB3's clipped policy loss, op for op (its advantages normalised per minibatch)."""
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        policy_loss_1 = advantages * ratio
        policy_loss_2 = advantages * th.clamp(ratio, 1 - clip_range, 1 + clip_range)
        return -th.min(policy_loss_1, policy_loss_2).mean()

    def _led_policy_loss(self, advantages: th.Tensor, ratio: th.Tensor, clip_range: float,
                         led: th.Tensor) -> th.Tensor:
        """The clipped policy loss over the steps the lead's action reaches the arm (``led``),
        their advantages normalised among themselves; 0 (no gradient) when there are none."""
        if not bool(led.any()):
            return ratio.sum() * 0.0
        return self._clipped_policy_loss(advantages[led], ratio[led], clip_range)

    def _record(self, pg_losses, value_losses, entropy_losses, clip_fractions, approx_kl_divs,
                loss, clip_range) -> None:
        """SB3's train/ logs, the same values: each list read as Python floats in one call
        (what SB3's per-minibatch .item() gives), then averaged by numpy as SB3 does."""
        def floats(ts):
            return th.stack(ts).tolist() if ts else []

        buf = self.rollout_buffer
        explained_var = explained_variance(buf.values.flatten(), buf.returns.flatten())
        log = self.logger.record
        log("train/entropy_loss", np.mean(floats(entropy_losses)))
        log("train/policy_gradient_loss", np.mean(floats(pg_losses)))
        log("train/value_loss", np.mean(floats(value_losses)))
        # SB3 keeps float32 numpy scalars here (.cpu().numpy()); np.mean of them is float32.
        log("train/approx_kl", np.mean(np.array(floats(approx_kl_divs), dtype=np.float32)))
        log("train/clip_fraction", np.mean(floats(clip_fractions)))
        log("train/loss", loss.item())
        log("train/explained_variance", explained_var)
        log("train/std", th.exp(self.policy.log_std).mean().item())
        log("train/n_updates", self._n_updates, exclude="tensorboard")
        log("train/clip_range", clip_range)


def linear_schedule(start: float):
    """SB3 learning-rate schedule: start at progress 1 (the first step), 0 at the end and after
    it. SB3 finishes the rollout that crosses --timesteps and updates on it with progress
    1 - steps / timesteps < 0: unclamped, that update's rate is negative (gradient ascent; a
    70,000-step run's third update, at 98,304 steps, took the value loss from 0.09 to 27)."""
    def schedule(progress_remaining: float) -> float:
        return start * max(progress_remaining, 0.0)
    return schedule


def _feature_start(config, feature: str) -> int | None:
    """The first column of ``feature`` in the newest stacked observation, or None."""
    from ..config import obs_layout

    env = getattr(config, "env", None)
    for name, start, _ in obs_layout(env.obs_features) if env is not None else ():
        if name == feature:
            return start
    return None


def _delay_columns(config) -> tuple[int, ...]:
    """The observation's columns holding the episode's three delays (the installation
    feature's first three), or () without that feature."""
    start = _feature_start(config, "installation")
    return () if start is None else (start, start + 1, start + 2)


def _plan_column(config) -> int | None:
    """The observation's plan_weight column (the hand's weight in the next goal), or None."""
    return _feature_start(config, "plan_weight")


def build_ppo(config, vec, fast: bool | None = None, update_threads: int | None = None) -> PPO:
    """The PPO model a training run uses, from its TrainConfig: FastPPO when
    ``config.fast_update`` (or ``fast``) says so, else SB3's PPO as it comes."""

    fast = getattr(config, "fast_update", True) if fast is None else fast
    ppo = {k: getattr(config, k) for k in ("n_steps", "batch_size", "n_epochs", "gamma",
                                           "gae_lambda", "learning_rate", "clip_range", "ent_coef",
                                           "target_kl")}
    if config.lr_schedule == "linear":
        ppo["learning_rate"] = linear_schedule(config.learning_rate)
    ppo.update(use_sde=getattr(config, "use_sde", False),
               sde_sample_freq=getattr(config, "sde_sample_freq", -1))
    policy_kwargs = dict(net_arch=list(config.net_arch), activation_fn=th.nn.Tanh,
                         log_std_init=config.log_std_init)
    if fast:
        ppo["update_threads"] = update_threads
        ppo.update(caps_temporal=getattr(config, "caps_temporal", 0.0),
                   caps_spatial=getattr(config, "caps_spatial", 0.0),
                   caps_sigma=getattr(config, "caps_sigma", 0.05),
                   caps_curvature=getattr(config, "caps_curvature", 0.0),
                   caps_curvature_delayed=getattr(config, "caps_curvature_delayed", None),
                   delay_columns=_delay_columns(config), plan_column=_plan_column(config))
        policy_kwargs["optimizer_kwargs"] = dict(eps=1e-5, foreach=True)  # SB3's eps for PPO
    if fast:
        return FastPPO(FastActorCriticPolicy, vec, seed=config.seed, device=config.device,
                       verbose=0, policy_kwargs=policy_kwargs, **ppo)
    return PPO("MlpPolicy", vec, seed=config.seed, device=config.device, verbose=0,
               policy_kwargs=policy_kwargs, **ppo)
