"""Learned policies from weights-only ``.npz`` actor files, run with numpy alone.

``LearnedPolicy`` runs one actor exported by ``training`` (``deck-sim train``), ``EnsemblePolicy`` several by the
mean of their actions; ``load_actor`` reads either kind of file. The DQN and A2C files are stable-baselines3
networks exported to the same format (``training.baselines.export_sb3``), so running them needs neither
stable-baselines3 nor ``training``.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import zipfile
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from deck_sim.scenes import POLICY_EPISODE_FIELDS

ACTOR_FORMAT = "deck_sim.actor/1"
"""DDPG's actors: ReLU hidden layers, a tanh output of 2 (implicit ``activation`` and ``head``)."""
ACTOR_FORMAT_V2 = "deck_sim.actor/2"
"""Any MLP policy: ``meta`` names the hidden ``activation`` (``ACTIVATIONS``) and the ``head`` (``HEADS``)."""
ACTOR_FORMAT_SETS = "deck_sim.actor/3"
"""DDPG's actors with one shared encoder per set of obstacles (Deep Sets, ``meta["sets"]`` names each set's keys):
every obstacle's features, beside the agent's own (the context), go through its set's MLP (ReLU after every
layer, arrays ``<set>.w<i>``, ``<set>.b<i>``), the set is max-pooled over its obstacles, and the head MLP (``w<i>``,
``b<i>``, ReLU hidden layers, tanh output of 2) reads the context and the pooled features.

The orders a reader must keep (``set_indices`` gives the indices, after normalising the whole flat vector):
an encoder's input is [the obstacle's row of each of the set's keys, in the order ``meta["sets"]`` lists them;
then the context]; the head's input is [the context; then each set's pooled features, in the order of
``meta["sets"]``]; the context is every key in no set, in the order of ``observation_keys``."""
OBSTACLE_SETS: dict[str, tuple[str, ...]] = {
    "movers": (
        "dynamic_obstacles", "predicted", "predicted_approach", "dynamic_size", "dynamic_nearest", "dynamic_heading",
        "dynamic_near", "predicted_near",
    ),
    "statics": ("static_obstacles", "static_nearest", "static_near"),
}
"""Observation keys whose rows are one obstacle each, by set: a set actor reads each row of a set's keys as one
element (mover ``j``'s position now, forecast and size together); every other key is the context."""
CRITIC_PREFIX = "critic."
"""An actor file of DDPG or MDDPG may carry the critic it was trained beside (``meta["critic"]``: ``heads``, the
number of Q heads, and ``twin_min_weight``): arrays ``critic.q<h>.w<i>``, ``critic.q<h>.b<i>`` of each head, an
MLP with ReLU hidden layers and one linear output over [the normalised observation, the action], as
``training.networks.Critic``. The heads combine as the run's TD target combines them: ``twin_min_weight`` times the
smaller plus the rest times the larger (TD3's minimum at 1)."""
SELECT_OFFSETS = "select.offsets"
"""With ``meta["select"]`` (``candidates``, ``spread``) and this (candidates, 2) array of offsets (unit normal
draws, fixed in the file), the policy selects its action by its critic (``LearnedPolicy.act_flat``)."""
ENSEMBLE_FORMAT = "deck_sim.ensemble/1"
"""Several actors of format 1, 2 or 3 with a continuous head (``tanh`` or ``clip``) in one file, acting by the mean of
their actions (``EnsemblePolicy``)."""
ACTIVATIONS = ("relu", "tanh")
HEADS = {
    "tanh": "mu(s) = tanh(MLP(s)), 2 outputs (DDPG's actor)",
    "clip": "clip(MLP(s), -1, 1), 2 outputs (the mean of A2C's Gaussian policy, as SB3's deterministic predict)",
    "argmax": "action_table[argmax MLP(s)], one output per row of the file's action_table (DQN's greedy action)",
}


class PolicyFileError(ValueError):
    """An actor file is missing, corrupt, or does not fit the environment it is asked to act in."""


_DAMAGED_FILE_ERRORS = (
    OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError, OverflowError,
    MemoryError, KeyError, struct.error,
)
"""What ``numpy.load`` and ``zipfile`` raise on a damaged ``.npz``: a bad zip structure or CRC (``BadZipFile``), a
damaged deflate stream (``zlib.error``), a flipped compression method (``NotImplementedError``) or encryption flag
(``RuntimeError``), headers cut short (``struct.error``, ``EOFError``, ``KeyError``), an ``.npy`` header naming an
impossible shape or dtype (``ValueError``, ``MemoryError``, ``OverflowError``)."""


def obstacle_sets(shapes: Mapping[str, Sequence[int]]) -> dict[str, list[str]]:
    """The sets of ``OBSTACLE_SETS`` that an observation of these ``shapes`` holds, each with its keys present; a
    set with no obstacle in this observation (a scene without movers: keys of shape (0, ...)) is left out, its
    empty keys then add nothing to the context."""
    out = {name: [k for k in keys if k in shapes and len(shapes[k]) and int(shapes[k][0]) > 0]
           for name, keys in OBSTACLE_SETS.items()}
    return {name: keys for name, keys in out.items() if keys}


def set_indices(
    shapes: Mapping[str, Sequence[int]], sets: Mapping[str, Sequence[str]]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Where a set actor's inputs lie in the flat observation (keys in the order of ``shapes``).

    Returns the context's indices (C,) (every key in no set) and, per set, an index array (n, f): row ``j`` holds
    obstacle ``j``'s features, its row of each of the set's keys in turn. ``ValueError`` if a set's keys do not
    share their first dimension, name a key the observation lacks, have no row per obstacle (a scalar shape),
    or if a set holds no obstacle or a key lies in two sets."""
    starts, start = {}, 0
    for k, s in shapes.items():
        starts[k] = start
        start += int(np.prod(s))
    listed = [k for keys in sets.values() for k in keys]
    in_sets = set(listed)
    if len(in_sets) < len(listed):
        twice = sorted({k for k in listed if listed.count(k) > 1})
        raise ValueError(f"set keys {twice} are listed more than once in {dict(sets)}")
    unknown = sorted(in_sets - set(shapes))
    if unknown:
        raise ValueError(f"set keys {unknown} are not in the observation {sorted(shapes)}")
    scalar = sorted(k for k in in_sets if len(shapes[k]) == 0)
    if scalar:
        raise ValueError(f"set keys {scalar} have no row per obstacle (shape ())")
    context = np.concatenate(
        [np.arange(starts[k], starts[k] + int(np.prod(s))) for k, s in shapes.items() if k not in in_sets]
        or [np.zeros(0, dtype=int)]
    )
    elements = {}
    for name, keys in sets.items():
        rows = {int(shapes[k][0]) for k in keys}
        if len(rows) != 1:
            raise ValueError(f"set {name!r}: keys {list(keys)} have first dimensions {sorted(rows)}, expected one")
        n = rows.pop()
        if n == 0:
            raise ValueError(f"set {name!r} holds no obstacle (keys {list(keys)} have 0 rows)")
        cols = []
        for k in keys:
            f = int(np.prod(shapes[k])) // n
            cols.append(starts[k] + np.arange(n)[:, None] * f + np.arange(f)[None, :])
        elements[name] = np.concatenate(cols, axis=1)
    return context.astype(np.int64), elements


class LearnedPolicy:
    """A trained policy network evaluated with numpy from a weights-only ``.npz`` file.

    The file holds the layers' weights and biases (``w0``, ``b0``, ...), the observation normaliser's statistics
    (``x -> clip((x - norm_mean) / norm_std, +-norm_clip)`` when ``norm_enabled``) and a JSON ``meta`` record:
    format, scene, algorithm, predictor, the observation keys and shapes it was trained on, the training
    configuration. Format ``deck_sim.actor/1`` is DDPG's actor, mu(s) = tanh(MLP(normalise(s))) with ReLU hidden
    layers; format ``deck_sim.actor/2`` names the hidden ``activation`` and the ``head`` in ``meta`` (``HEADS``;
    ``argmax`` also needs an ``action_table`` array; ``input_dtype: float32`` rounds observations to float32 first,
    as the policy saw them in training); format ``deck_sim.actor/3`` is DDPG's set actor (``ACTOR_FORMAT_SETS``:
    ``meta["sets"]`` names each set's keys, arrays ``<set>.w<i>``, ``<set>.b<i>`` its encoder). ``act`` flattens
    the observation dict in the trained key order and checks every shape, so a policy asked to act on another
    scene or predictor fails with a clear error.
    """

    def __init__(self, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any], source: str = "<arrays>") -> None:
        self.meta = dict(meta)
        self.source = source
        self.arrays = {k: np.asarray(v) for k, v in arrays.items()}  # as given (an ensemble file stores them again)
        fmt = self.meta.get("format")
        if fmt == ENSEMBLE_FORMAT:
            raise PolicyFileError(
                f"{source}: an ensemble of {len(self.meta.get('members') or [])} actors, not one actor; read it with "
                "deck_sim.policies.load_actor (or EnsemblePolicy.load)"
            )
        formats = (ACTOR_FORMAT, ACTOR_FORMAT_V2, ACTOR_FORMAT_SETS)
        if fmt not in formats:
            raise PolicyFileError(f"{source}: format {fmt!r}, expected one of {formats}")
        try:
            self.keys = tuple(str(k) for k in self.meta["observation_keys"])
            recorded = {str(k): tuple(int(n) for n in v) for k, v in self.meta["observation_shapes"].items()}
            if set(recorded) != set(self.keys) or len(self.keys) != len(recorded):
                raise ValueError(f"observation_keys {list(self.keys)} and observation_shapes {sorted(recorded)} "
                                 "name different keys")
            self.shapes = {k: recorded[k] for k in self.keys}  # in the flat vector's order, whatever the record's
            self.activation = str(self.meta["activation"]) if fmt == ACTOR_FORMAT_V2 else "relu"
            self.head = str(self.meta["head"]) if fmt == ACTOR_FORMAT_V2 else "tanh"
            self.weights, self.biases = _layers(arrays, "")
            self.sets: dict[str, list[str]] = _sets_record(self.meta["sets"]) if fmt == ACTOR_FORMAT_SETS else {}
            self.encoders = {name: _layers(arrays, f"{name}.") for name in self.sets}
            self.norm_enabled = bool(_real(arrays, "norm_enabled"))
            self.norm_mean = _real(arrays, "norm_mean")
            self.norm_std = _real(arrays, "norm_std")
            self.norm_clip = float(_real(arrays, "norm_clip"))
            self.action_table = _real(arrays, "action_table") if self.head == "argmax" else None
            self.critic_heads = [_layers(arrays, f"{CRITIC_PREFIX}q{h}.")
                                 for h in range(int(self.meta["critic"]["heads"]))] if "critic" in self.meta else []
            self.twin_min_weight = float(self.meta["critic"].get("twin_min_weight", 1.0)) if self.critic_heads \
                else 1.0
            if not 0.0 <= self.twin_min_weight <= 1.0:
                raise ValueError(f"meta['critic']['twin_min_weight'] is {self.twin_min_weight}, not in [0, 1]")
            self.offsets = None
            if "select" in self.meta:
                spread = float(self.meta["select"]["spread"])
                if not (math.isfinite(spread) and spread > 0):
                    raise ValueError(f"meta['select']['spread'] is {spread}, not a positive number")
                self.offsets = spread * _real(arrays, SELECT_OFFSETS)
                if self.offsets.shape != (int(self.meta["select"]["candidates"]), 2):
                    raise ValueError(f"{SELECT_OFFSETS} has shape {self.offsets.shape}, meta['select'] asks for "
                                     f"{self.meta['select']['candidates']} candidates of 2")
            self._read_scene_overrides()  # a malformed record fails here, on loading, not when the scene is built
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError) as err:
            raise PolicyFileError(f"{source}: not a complete deck_sim actor ({err!r} missing or malformed)") from err
        if self.activation not in ACTIVATIONS:
            raise PolicyFileError(f"{source}: activation {self.activation!r}, expected one of {ACTIVATIONS}")
        if self.head not in HEADS:
            raise PolicyFileError(f"{source}: head {self.head!r}, expected one of {tuple(HEADS)}")
        dim = int(sum(np.prod(s) for s in self.shapes.values()))
        head_in = dim
        if self.sets:
            try:
                self._context, self._elements = set_indices(self.shapes, self.sets)
            except ValueError as err:
                raise PolicyFileError(f"{source}: {err}") from err
        heads = {f"{CRITIC_PREFIX}q{h}" for h in range(len(self.critic_heads))}  # (the critic's own layers)
        stray = sorted(k for k in arrays if re.fullmatch(r"(.+)\.[wb]\d+", k) and k.split(".")[0] not in self.sets
                       and k.rpartition(".")[0] not in heads)
        critic_stray = [k for k in stray if k.startswith(CRITIC_PREFIX)]
        if critic_stray:
            raise PolicyFileError(f"{source}: arrays {critic_stray[:5]} are critic layers, but meta['critic'] names "
                                  f"{len(self.critic_heads)} heads")
        if stray:
            raise PolicyFileError(f"{source}: arrays {stray[:5]} are set encoders, but the file's format {fmt!r} "
                                  f"names the sets {sorted(self.sets)}")
        if self.sets:
            head_in = len(self._context)
            for name, (ws, bs) in self.encoders.items():
                if not ws:
                    raise PolicyFileError(f"{source}: set {name!r} has no encoder layers ({name}.w0, ...)")
                _check_layers(ws, bs, self._elements[name].shape[1] + len(self._context), f"{source}, set {name!r}")
                head_in += ws[-1].shape[0]
        _check_layers(self.weights, self.biases, head_in, source)
        if self.action_table is not None:
            table = self.action_table
            if table.ndim != 2 or table.shape[1] != 2 or not np.all(np.abs(table) <= 1.0):
                raise PolicyFileError(f"{source}: action_table has shape {table.shape}; expected (n, 2) in [-1, 1]")
        outputs = 2 if self.action_table is None else len(self.action_table)
        norm_ok = self.norm_mean.shape == (dim,) and self.norm_std.shape == (dim,)
        if not self.weights or self.weights[-1].shape[0] != outputs or not norm_ok:
            raise PolicyFileError(f"{source}: expected {dim} inputs and {outputs} outputs, normaliser of size {dim}")
        for h, (ws, bs) in enumerate(self.critic_heads):
            if not ws:
                raise PolicyFileError(f"{source}: meta['critic'] names {len(self.critic_heads)} heads, head {h} has "
                                      f"no layers ({CRITIC_PREFIX}q{h}.w0, ...)")
            _check_layers(ws, bs, dim + 2, f"{source}, critic head {h}")
            if ws[-1].shape[0] != 1:
                raise PolicyFileError(f"{source}: critic head {h} has {ws[-1].shape[0]} outputs, expected 1")
        if self.offsets is not None and not self.critic_heads:
            raise PolicyFileError(f"{source}: meta['select'] asks to select actions by the critic, but the file "
                                  "carries none (meta['critic'])")
        if self.offsets is not None and self.action_table is not None:
            raise PolicyFileError(f"{source}: selection by the critic needs a continuous action, not head 'argmax'")
        encoders = [a for ws, bs in (*self.encoders.values(), *self.critic_heads) for a in (*ws, *bs)]
        if not all(np.all(np.isfinite(a)) for a in (*self.weights, *self.biases, *encoders, self.norm_mean,
                                                     self.norm_std, *([] if self.offsets is None else
                                                                      [self.offsets]))):
            raise PolicyFileError(f"{source}: the actor holds NaN or infinite weights")
        if self.norm_enabled and not np.all(self.norm_std > 0):
            raise PolicyFileError(f"{source}: the normaliser has a zero or negative std")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> LearnedPolicy:
        """Read an actor file written by ``training`` (``actor.npz``); ``PolicyFileError`` if it cannot (an
        ensemble file included: ``load_actor`` reads either kind)."""
        arrays, meta = _read_actor_file(path)
        return cls(arrays, meta, source=str(path))

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the actor as a weights-only ``.npz`` (compressed) that ``load`` reads back, atomically
        (``write_actor_file``)."""
        return write_actor_file(path, self.arrays, self.meta)

    @property
    def predictor(self) -> str:
        """The predictor whose forecasts the actor was trained on (``none`` for DDPG)."""
        return str(self.meta.get("predictor", "none"))

    @property
    def scene_overrides(self) -> dict[str, Any]:
        """Scene fields an environment needs to give this actor its observation (``deck_sim.load`` keywords):
        the predictor, ``episode__obstacle_shape`` for an actor trained on the obstacles' shapes,
        ``episode__mover_size`` for one trained on the movers' sizes, ``episode__static_size`` for one trained on
        the static obstacles' footprints, ``episode__predicted_approach`` for one trained on its forecast's
        closest approaches, ``episode__near_obstacles`` for one trained
        on the obstacles within its near field, ``episode__predicted_near`` for one trained on its forecast at that
        field's scale, the ``episode__near_steps`` and
        ``episode__route_steps`` it was trained with, and every field of ``scenes.POLICY_EPISODE_FIELDS`` its
        training overrode (the observation's keys and shapes cannot tell those)."""
        return self._read_scene_overrides()

    def _read_scene_overrides(self) -> dict[str, Any]:
        """``scene_overrides`` read from ``meta`` as it is now (``TypeError`` or ``ValueError`` if malformed)."""
        out: dict[str, Any] = {"episode__predictor": self.predictor}
        if "static_nearest" in self.keys:
            out["episode__obstacle_shape"] = True
        if "dynamic_size" in self.keys:
            out["episode__mover_size"] = True
        if "static_size" in self.keys:
            out["episode__static_size"] = True
        if "static_near" in self.keys:
            out["episode__near_obstacles"] = True
        if "predicted_approach" in self.keys:
            out["episode__predicted_approach"] = True
        if "predicted_near" in self.keys:
            out["episode__predicted_near"] = True
        trained = dict(self.meta.get("scene_overrides") or {})
        for field in POLICY_EPISODE_FIELDS:
            if trained.get(f"episode__{field}") is not None:
                out[f"episode__{field}"] = trained[f"episode__{field}"]
        # (an actor trained on a scene file that sets ``near_steps`` itself records no override: that file gives
        # it its near field, and any other scene is refused by ``flatten``)
        if "target_near" in self.keys and "episode__near_steps" in trained:
            out["episode__near_steps"] = int(trained["episode__near_steps"])
        if "route" in self.keys:  # its length is in the observation's shape, but the scene must be asked for it
            out["episode__route_steps"] = int(self.shapes["route"][0])
        return out

    def reset(self) -> None:
        """The actor has no memory."""

    def flatten(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """The observation dict as the flat vector the actor was trained on; ``PolicyFileError`` on a mismatch."""
        parts = []
        for k in self.keys:
            if k not in observation:
                raise PolicyFileError(
                    f"{self.source}: the actor needs observation {k!r}, which this environment does not give "
                    f"(trained on scene {self.meta.get('scene')!r} with predictor {self.predictor!r})"
                )
            v = np.asarray(observation[k], dtype=np.float64)
            if v.shape != self.shapes[k]:
                raise PolicyFileError(
                    f"{self.source}: observation {k!r} has shape {v.shape}, the actor was trained on "
                    f"{self.shapes[k]} (scene {self.meta.get('scene')!r})"
                )
            parts.append(v.ravel())
        return np.concatenate(parts)

    def act_flat(self, x: np.ndarray) -> np.ndarray:
        """Actions (..., 2) for flat observations (..., dim): the actor's, or, where the file asks for selection
        (``selects``), the one its critic selects: the actor proposes ``a``; the candidates are ``a`` and
        ``clip(a + spread * offset_j, -1, 1)`` for each of the file's fixed offsets; the action is the candidate of
        the largest Q (the heads combined as the run's TD target combined them), ``a`` itself on a tie."""
        x = self._normalised(x)
        proposal = self._actor(x)
        return proposal if self.offsets is None else self._select(x, proposal)

    @property
    def selects(self) -> bool:
        """Whether the policy selects its actions by its critic (``act_flat``)."""
        return self.offsets is not None

    def q_values(self, x: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The critic's Q (..., k) of flat observations (..., dim) with each of k actions (..., k, 2), the heads
        combined as the run's TD target combined them; in the run's reward units times its ``reward_scale``."""
        if not self.critic_heads:
            raise PolicyFileError(f"{self.source}: carries no critic (meta['critic'])")
        return self._q(self._normalised(x), np.asarray(actions, dtype=np.float64))

    def _select(self, x: np.ndarray, proposal: np.ndarray) -> np.ndarray:
        """The candidate of largest Q around ``proposal`` (..., 2) for normalised observations ``x`` (..., dim)."""
        cand = np.concatenate([proposal[..., None, :],
                               np.clip(proposal[..., None, :] + self.offsets, -1.0, 1.0)], axis=-2)
        best = np.argmax(self._q(x, cand), axis=-1)
        return np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]

    def _q(self, x: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Combined Q (..., k) of normalised observations (..., dim) with actions (..., k, 2)."""
        h = np.concatenate([np.broadcast_to(x[..., None, :], (*actions.shape[:-1], x.shape[-1])), actions], axis=-1)
        heads = []
        for ws, bs in self.critic_heads:
            y = h
            for i, (w, b) in enumerate(zip(ws, bs, strict=True)):
                y = y @ w.T + b
                if i < len(ws) - 1:
                    y = np.maximum(y, 0.0)
            heads.append(y[..., 0])
        q = np.min(heads, axis=0)
        if len(heads) > 1 and self.twin_min_weight < 1.0:
            q = self.twin_min_weight * q + (1.0 - self.twin_min_weight) * np.max(heads, axis=0)
        return q

    def _normalised(self, x: np.ndarray) -> np.ndarray:
        """Flat observations (..., dim) as the networks read them (float64)."""
        x = np.asarray(x, dtype=np.float64)
        if self.meta.get("input_dtype") == "float32":  # trained on float32 observations (stable-baselines3)
            x = x.astype(np.float32).astype(np.float64)
        if self.norm_enabled:
            x = np.clip((x - self.norm_mean) / self.norm_std, -self.norm_clip, self.norm_clip)
        return x

    def _actor(self, x: np.ndarray) -> np.ndarray:
        """The actor's actions (..., 2) for normalised flat observations (..., dim)."""
        if self.sets:
            x = self._pooled(x)
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = x @ w.T + b
            if i < len(self.weights) - 1:
                x = np.maximum(x, 0.0) if self.activation == "relu" else np.tanh(x)
        if self.head == "tanh":
            return np.tanh(x)
        if self.head == "clip":
            return np.clip(x, -1.0, 1.0)
        return self.action_table[np.argmax(x, axis=-1)]

    def _pooled(self, x: np.ndarray) -> np.ndarray:
        """A set actor's head input (..., C + sum of pooled widths) for normalised flat observations (..., dim)."""
        context = x[..., self._context]
        parts = [context]
        for name, (ws, bs) in self.encoders.items():
            elements = x[..., self._elements[name]]  # (..., n, f)
            h = np.concatenate([elements, np.broadcast_to(context[..., None, :], (*elements.shape[:-1],
                                                                                   context.shape[-1]))], axis=-1)
            for w, b in zip(ws, bs, strict=True):
                h = np.maximum(h @ w.T + b, 0.0)
            parts.append(h.max(axis=-2))
        return np.concatenate(parts, axis=-1)

    def act(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """The actor's action (2,) for one observation dict."""
        return self.act_flat(self.flatten(observation))


def selecting(policy: LearnedPolicy, candidates: int = 64, spread: float = 0.3, seed: int = 0) -> LearnedPolicy:
    """A copy of ``policy`` (one actor that carries its critic) that selects its actions by that critic
    (``LearnedPolicy.act_flat``): ``candidates`` offsets drawn once from the unit normal (``seed``), stored in the
    copy's arrays, scaled by ``spread`` (action units; the action box is [-1, 1] per axis). Its ``meta`` records
    both. ``save`` writes it as an actor file that every tool reading actor files plays with selection."""
    if not isinstance(policy, LearnedPolicy):
        raise PolicyFileError(f"{getattr(policy, 'source', policy)}: selection by the critic is for one actor; an "
                              "ensemble's members carry a critic each and no common one")
    if not policy.critic_heads:
        raise PolicyFileError(f"{policy.source}: carries no critic to select actions by (actor files of DDPG and "
                              "MDDPG runs carry their critic; older files, stable-baselines3's and those of a "
                              "LayerNorm critic do not)")
    if candidates < 1 or not (math.isfinite(spread) and spread > 0):
        raise ValueError(f"selection needs at least 1 candidate and a positive spread, got {candidates} and {spread}")
    arrays = {**policy.arrays,
              SELECT_OFFSETS: np.random.default_rng(seed).standard_normal((candidates, 2)).astype(np.float32)}
    meta = {**policy.meta, "select": {"candidates": int(candidates), "spread": float(spread), "seed": int(seed)}}
    return LearnedPolicy(arrays, meta, source=policy.source)


def _sets_record(record: Any) -> dict[str, list[str]]:
    """A set actor's ``meta["sets"]`` (set name -> its observation keys) checked; ``ValueError`` if malformed."""
    if not isinstance(record, dict) or not record:
        raise ValueError(f"'sets' must map each set's name to its keys, got {record!r}")
    for name, keys in record.items():
        if not isinstance(keys, list) or not keys or not all(isinstance(k, str) for k in keys):
            raise ValueError(f"'sets': set {name!r} must list its observation keys, got {keys!r}")
    return {str(name): list(keys) for name, keys in record.items()}


def _real(arrays: Mapping[str, np.ndarray], key: str) -> np.ndarray:
    """Array ``key`` as float64; ``KeyError`` if absent, ``ValueError`` unless it holds real numbers (bool, integer or
    float: not complex, text or bytes)."""
    a = np.asarray(arrays[key])
    if a.dtype.kind not in "biuf":
        raise ValueError(f"array {key!r} has dtype {a.dtype}, not a real number type")
    return a.astype(np.float64, copy=False)


def _layers(arrays: Mapping[str, np.ndarray], prefix: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The weights and biases ``<prefix>w<i>``, ``<prefix>b<i>`` of one MLP (as float64), in order."""
    n = sum(1 for k in arrays if re.fullmatch(re.escape(prefix) + r"w\d+", k))
    return ([_real(arrays, f"{prefix}w{i}") for i in range(n)], [_real(arrays, f"{prefix}b{i}") for i in range(n)])


def _check_layers(weights: Sequence[np.ndarray], biases: Sequence[np.ndarray], inputs: int, source: str) -> None:
    """``PolicyFileError`` unless each layer's weight (out, in) and bias (out,) follow from ``inputs``."""
    sizes = [inputs] + [w.shape[0] if w.ndim == 2 else -1 for w in weights]
    for i, (w, b) in enumerate(zip(weights, biases, strict=True)):
        if w.ndim != 2 or w.shape[1] != sizes[i] or b.shape != (w.shape[0],):
            raise PolicyFileError(f"{source}: layer {i} has weight {w.shape} and bias {b.shape}, "
                                  f"which do not follow a layer of {sizes[i]} inputs")


class EnsemblePolicy:
    """Several actors that read one observation, acting together: the mean of their actions.

    Averaging the actions of actors trained from different seeds cancels part of each one's own errors (measured
    in ``docs/training.md``, "Switches and their measured effects"). Every
    member must be a ``LearnedPolicy`` with a continuous head (``tanh`` or ``clip``: a mean of DQN's argmax rows
    is not DQN's policy) trained on the same observation keys and shapes and the same ``scene_overrides``, so one
    environment serves them all; the mean of actions in [-1, 1] stays in [-1, 1].

    Its file (``save``; format ``deck_sim.ensemble/1``) holds each member's arrays under ``m<i>/`` and a ``meta``
    record whose ``members`` list the members' own records; its other fields are the first member's (scene,
    algorithm, predictor, observation, and also ``config``, ``trained_steps``, ``git_commit`` and ``polished``,
    which may differ between members: read those from ``members``), so code that reads one actor's record reads an
    ensemble's. A member's critic and its selection by it (``selecting``) stay the member's: a member that selects
    picks its own action by its own critic before the mean is taken.
    """

    def __init__(self, members: Sequence[LearnedPolicy], source: str = "<members>") -> None:
        self.members = list(members)
        self.source = source
        for i, m in enumerate(self.members):
            if not isinstance(m, LearnedPolicy):
                raise PolicyFileError(f"{source}: member {i} is a {type(m).__name__}, not one actor (LearnedPolicy); "
                                      "an ensemble's members join as they are (EnsemblePolicy([*e.members, ...]))")
        if len(self.members) < 2:
            raise PolicyFileError(f"{source}: an ensemble needs two or more actors, got {len(self.members)}")
        first = self.members[0]
        for i, m in enumerate(self.members):
            if m.head not in ("tanh", "clip"):
                raise PolicyFileError(f"{source}: member {i} ({m.source}) has head {m.head!r}; only actors with a "
                                      "continuous action (head 'tanh' or 'clip') can be averaged")
            if (m.keys, m.shapes) != (first.keys, first.shapes):
                raise PolicyFileError(f"{source}: member {i} ({m.source}) reads observation {dict(m.shapes)}, "
                                      f"member 0 ({first.source}) reads {dict(first.shapes)}")
            if m.scene_overrides != first.scene_overrides:
                raise PolicyFileError(f"{source}: member {i} ({m.source}) needs scene fields {m.scene_overrides}, "
                                      f"member 0 ({first.source}) needs {first.scene_overrides}")
        self.keys, self.shapes = first.keys, first.shapes
        own = {k: v for k, v in first.meta.items() if k not in ("critic", "select")}  # (each member's, not the mean's)
        self.meta = {**own, "format": ENSEMBLE_FORMAT, "combine": "mean",
                     "members": [dict(m.meta) for m in self.members]}

    @classmethod
    def from_arrays(
        cls, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any], source: str = "<arrays>"
    ) -> EnsemblePolicy:
        """The ensemble stored as ``save`` writes it (member ``i``'s arrays under ``m<i>/``)."""
        if meta.get("format") != ENSEMBLE_FORMAT:
            raise PolicyFileError(f"{source}: format {meta.get('format')!r}, expected {ENSEMBLE_FORMAT!r}")
        records = meta.get("members")
        if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
            raise PolicyFileError(f"{source}: the ensemble's 'members' record is not a list of actor records")
        if meta.get("combine", "mean") != "mean":
            raise PolicyFileError(f"{source}: combine {meta.get('combine')!r}, expected 'mean'")
        members = []
        for i, record in enumerate(records):
            if record.get("format") == ENSEMBLE_FORMAT:
                raise PolicyFileError(f"{source}: member {i} is itself an ensemble record; members are single actors")
            prefix = f"m{i}/"
            mine = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
            members.append(LearnedPolicy(mine, record, source=f"{source}, member {i}"))
        ensemble = cls(members, source=source)
        owners = {f"m{i}" for i in range(len(records))}
        stray = sorted(k for k in arrays if k.partition("/")[0] not in owners or "/" not in k)
        if stray:
            raise PolicyFileError(f"{source}: arrays {stray[:5]} belong to no member of the ensemble")
        return ensemble

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> EnsemblePolicy:
        """Read an ensemble file written by ``save``; ``PolicyFileError`` if it cannot."""
        arrays, meta = _read_actor_file(path)
        return cls.from_arrays(arrays, meta, source=str(path))

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the ensemble as one weights-only ``.npz`` (compressed), atomically: a reader finds the old file or
        the new one, never a part; an existing file is untouched if writing fails."""
        arrays = {f"m{i}/{k}": v for i, m in enumerate(self.members) for k, v in m.arrays.items()}
        return write_actor_file(path, arrays, self.meta)

    @property
    def predictor(self) -> str:
        """The predictor the members were trained on."""
        return self.members[0].predictor

    @property
    def scene_overrides(self) -> dict[str, Any]:
        """The scene fields the members need (the same for all: ``LearnedPolicy.scene_overrides``)."""
        return self.members[0].scene_overrides

    def reset(self) -> None:
        """Actors have no memory."""

    def flatten(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """The flat observation the members read (``LearnedPolicy.flatten``)."""
        return self.members[0].flatten(observation)

    def act_flat(self, x: np.ndarray) -> np.ndarray:
        """The members' mean action (..., 2) for flat observations (..., dim)."""
        return np.mean([m.act_flat(x) for m in self.members], axis=0)

    def act(self, observation: Mapping[str, np.ndarray]) -> np.ndarray:
        """The members' mean action (2,) for one observation dict."""
        return self.act_flat(self.flatten(observation))


def write_actor_file(path: str | os.PathLike[str], arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any],
                     compress: bool = True) -> Path:
    """Write an actor or ensemble file: ``arrays`` and the JSON ``meta`` record in one ``.npz`` (``compress``:
    zip-deflated), atomically: a reader finds the old file or the new one, never a part, and an existing file is
    untouched if writing fails. Returns the path written."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    save = np.savez_compressed if compress else np.savez
    try:
        save(tmp, meta=np.array(json.dumps(dict(meta))), **arrays)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _read_actor_file(path: str | os.PathLike[str]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays and the JSON ``meta`` record of an actor or ensemble file; ``PolicyFileError`` if unreadable."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except FileNotFoundError as err:
        raise PolicyFileError(f"{path}: no such actor file") from err
    except IsADirectoryError as err:
        raise PolicyFileError(f"{path}: is a directory, not an actor file") from err
    except _DAMAGED_FILE_ERRORS as err:
        what = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
        raise PolicyFileError(f"{path}: not a readable actor file, damaged or not an .npz ({what})") from err
    if "meta" not in arrays:
        raise PolicyFileError(f"{path}: not a deck_sim actor file (no 'meta' record)")
    try:
        meta = json.loads(str(arrays.pop("meta")))
    except json.JSONDecodeError as err:
        raise PolicyFileError(f"{path}: the 'meta' record is not JSON ({err})") from err
    if not isinstance(meta, dict):
        raise PolicyFileError(f"{path}: the 'meta' record is not a JSON object")
    return arrays, meta


def load_actor(path: str | os.PathLike[str]) -> LearnedPolicy | EnsemblePolicy:
    """The learned policy in ``path``: one actor (``LearnedPolicy``) or an ensemble (``EnsemblePolicy``), as its
    ``meta`` record's format says; ``PolicyFileError`` naming the problem if the file cannot serve."""
    arrays, meta = _read_actor_file(path)
    if meta.get("format") == ENSEMBLE_FORMAT:
        return EnsemblePolicy.from_arrays(arrays, meta, source=str(path))
    return LearnedPolicy(arrays, meta, source=str(path))

