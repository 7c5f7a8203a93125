"""``mjsafe.Env``: one episode stepped control tick by control tick, Gymnasium-style.

The agent's action is the nominal input u0 (the scenario's nominal is replaced by
``nominal.kind = "external"``): at every tick the safety filter of the scenario filters it and
the delay queues hold it for their delays before the plant applies it, exactly as in
``mjsafe.run`` (the same Rust loop, log and analysis). With ``gymnasium`` installed, ``Env`` is a
``gymnasium.Env`` (spaces, ``reset(seed=…)``, ``step``); without it, the same methods work on
their own. See docs/python.md, "Step by step".
"""

from __future__ import annotations

import math
import os
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from mjsafe import _core  # type: ignore[attr-defined]

_gym: Any
_spaces: Any
try:  # Gymnasium is optional: the environment works without it.
    import gymnasium as _gym
    from gymnasium import spaces as _spaces

    _Base: type = _gym.Env
except ImportError:  # pragma: no cover - exercised only without gymnasium
    _gym = None
    _spaces = None
    _Base = object

Reward = Callable[[np.ndarray, dict], float]


class Env(_Base):  # type: ignore[misc, valid-type]
    """A scenario as an environment: ``reset()`` starts an episode, ``step(action)`` takes one
    control tick (the plant steps of one control period) with ``action`` as the nominal input.

    Args:
        path: the scenario file (TOML).
        set: overrides as ``mjsafe.run`` takes them.
        out: a directory: each episode's MCAP log is written there as ``episode-<n>.mcap``
            (n from 0). None: episodes are analysed in memory, no file is written.
        drive: True (default): the action is the nominal input (``nominal.kind = "external"``).
            False: the scenario's own nominal runs and ``step()`` takes no action (``None``): an
            episode observed tick by tick.
        reward: ``reward(observation, info) -> float`` of a step. Default: the progress toward
            the scenario's ``[goal]`` in the step (m: its distance before minus after); a
            scenario without a goal needs one.
        terminate_on_collision: end the episode (``terminated``) at the first collision.

    Observation: the state x(t) (``state_names``), float64. ``info`` of a step: ``time`` (s),
    ``barriers`` (``{name: {"h", "clearance", "known", "obstacle"}}`` at x(t), each h in its
    barrier's own unit, clearance in m), ``issued`` (the tick's ``nominal`` and ``filtered`` commands), ``filter`` (``active``,
    ``correction``, ``infeasible``, ``unmet``), ``events`` (``/event``s of the step), ``cost``
    (1.0 when a collision started in the step, else 0.0), ``error`` (why the run stopped, or
    None), ``distance_to_goal`` (m, with a goal).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        path: str | os.PathLike[str],
        set: Mapping[str, Any] | None = None,
        out: str | os.PathLike[str] | None = None,
        drive: bool = True,
        reward: Reward | None = None,
        terminate_on_collision: bool = True,
    ) -> None:
        if set is not None and not isinstance(set, Mapping):
            raise TypeError(f"set: expected a dict of dotted keys, not a {type(set).__name__}")
        if reward is not None and not callable(reward):
            raise TypeError(f"reward: expected a callable reward(observation, info), not a {type(reward).__name__}")
        self.path = os.fspath(path)
        self._set = dict(set or {})
        self._drive = bool(drive)
        self._out = None if out is None else os.fspath(out)
        if self._out is not None and not os.path.isdir(self._out):
            raise ValueError(f"out: {self._out} is not a directory (episodes are written there as episode-<n>.mcap)")
        self._reward = reward
        self._terminate_on_collision = bool(terminate_on_collision)
        self._episodes = 0
        self._stepper: Any = None
        self._seed: int | None = None
        self._last_h: dict[str, float] = {}
        self._final_obs = np.zeros(0)
        self._done = True
        #: The result (``mjsafe.RunResult``) of the last finished episode, or None.
        self.result: Any = None
        probe = self._start(None, None)
        described = probe.describe()
        probe.finish("end_here")
        self.state_names: list[str] = list(described["state_names"])
        self.channels: list[str] = list(described["channels"])
        metadata = described["metadata"]
        self._planar = described["planar_position"]
        goal = metadata.get("goal_position")
        self.goal: tuple[float, float] | None = None if goal is None else tuple(float(v) for v in goal.split())  # type: ignore[assignment]
        self.goal_radius: float | None = None if goal is None else float(metadata["goal_radius"])
        if self._reward is None and (self.goal is None or self._planar is None):
            raise ValueError(
                f"{self.path}: the scenario has no [goal] disc for the default reward (position and "
                "radius; a region of polygons, e.g. a CommonRoad goal, has none) or its vehicle is not planar: "
                "give reward=callable(observation, info)"
            )
        if _spaces is not None:
            n, r = len(self.state_names), len(self.channels)
            self.observation_space = _spaces.Box(-np.inf, np.inf, (n,), np.float64)
            # The vehicle's input limits where it has them (the car's steering), else ±∞.
            limits = np.array(described["input_limits"], dtype=np.float64).reshape(r, 2)
            low, high = (limits[:, 0], limits[:, 1]) if self._drive else (np.zeros(0), np.zeros(0))
            self.action_space = _spaces.Box(low, high, (len(low),), np.float64)

    def _start(self, seed: int | None, log: str | None) -> Any:
        overrides = dict(self._set)
        if self._drive:
            overrides["nominal"] = {"kind": "external"}
        if seed is not None:
            overrides["seed"] = int(seed)
        return _core.Stepper(self.path, overrides, log)

    # Gymnasium's API ------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Starts a new episode (the previous one, if unfinished, ends where it is and its log is
        written); ``seed`` sets the scenario's ``seed`` (noise, jitter, actuation) for this and
        later episodes. Returns (x(0), info)."""
        if _gym is not None:
            super().reset(seed=seed)
        if seed is not None:
            self._seed = int(seed)
        self._finish("end_here")
        log = None if self._out is None else os.path.join(self._out, f"episode-{self._episodes}.mcap")
        self._stepper = self._start(self._seed, log)
        self._episodes += 1
        self._collided = False
        self._done = False
        obs = self._observe()
        info = self._info(self._stepper.latest(), obs)
        return obs, info

    def step(self, action: Sequence[float] | np.ndarray | None) -> tuple[np.ndarray, float, bool, bool, dict]:
        """One control tick with ``action`` as the nominal input (one value per channel).
        Returns (observation, reward, terminated, truncated, info): terminated at a collision
        (``terminate_on_collision``), at the goal, or when the run stopped on an error;
        truncated at the scenario's duration."""
        if self._stepper is None or self._done:
            raise RuntimeError("the episode is over (or not started): call reset()")
        if self._drive:
            values = np.asarray(action, dtype=np.float64).reshape(-1)
            if values.shape != (len(self.channels),):
                raise ValueError(f"action: expected {len(self.channels)} values ({', '.join(self.channels)}), found {values.size}")
            self._stepper.set_input(values.tolist())
        elif action is not None and np.asarray(action).size:
            raise ValueError("action: this environment runs the scenario's own nominal (drive=False): step(None)")
        before = self._distance(self._observe())
        step, steps, per_tick, _ = self._stepper.clock()
        ended = self._stepper.advance(per_tick - step % per_tick)
        step, steps, _, _ = self._stepper.clock()
        if not ended and step >= steps:
            ended = self._stepper.advance(1)  # logs x(T) and the episode's end
        obs = self._observe()
        latest = self._stepper.latest()
        info = self._info(latest, obs)
        collided = any(e["kind"] == "collision_start" for e in latest["events"])
        info["cost"] = 1.0 if collided else 0.0
        errors = [e["message"] for e in latest["events"] if e["kind"] == "error"]
        info["error"] = errors[0] if errors else None
        at_goal = info.get("distance_to_goal") is not None and info["distance_to_goal"] <= self.goal_radius
        terminated = bool(info["error"] or at_goal or (collided and self._terminate_on_collision))
        truncated = bool(ended and not terminated)
        if self._reward is not None:
            reward = float(self._reward(obs, info))
        else:
            reward = before - info["distance_to_goal"]
        if terminated or truncated:
            self._done = True
            self._finish("end_here")
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Ends the current episode where it is (its log is written)."""
        self._finish("end_here")

    # Observing between ticks ------------------------------------------------------------------

    @property
    def time(self) -> float:
        """t of the current state (s)."""
        step, _, _, h = self._live().clock()
        return step * h

    @property
    def state(self) -> np.ndarray:
        """x(t), the plant's state now."""
        return self._observe()

    def queues(self) -> list[dict[str, Any]]:
        """Per channel: ``channel``, its ``delay`` now (s) and the commands ``issued`` and still
        held, ``(issue time, value)`` oldest first."""
        return self._live().queues()

    def barriers(self) -> dict[str, float]:
        """h of every barrier at the current state (``{name: h}``, each in its own unit)."""
        return dict(self._last_h)

    # Internals -----------------------------------------------------------------------------------

    def _live(self) -> Any:
        if self._stepper is None or self._stepper.finished:
            raise RuntimeError("no episode is running: call reset()")
        return self._stepper

    def _observe(self) -> np.ndarray:
        if self._stepper is None or self._stepper.finished:
            return self._final_obs
        self._final_obs = np.asarray(self._stepper.state(), dtype=np.float64)
        return self._final_obs

    def _distance(self, obs: np.ndarray) -> float | None:
        if self.goal is None or self._planar is None:
            return None
        i, j = self._planar
        return math.hypot(obs[i] - self.goal[0], obs[j] - self.goal[1])

    def _info(self, latest: dict, obs: np.ndarray) -> dict[str, Any]:
        step, _, _, h = self._stepper.clock()
        barriers = {b.pop("name"): b for b in self._stepper.barriers()}
        self._last_h = {name: b["h"] for name, b in barriers.items()}
        info: dict[str, Any] = {
            "time": step * h,
            "barriers": barriers,
            "issued": latest["issued"],
            "filter": latest["filter"],
            "events": latest["events"],
            "cost": 0.0,
            "error": None,
        }
        distance = self._distance(obs)
        if distance is not None:
            info["distance_to_goal"] = distance
        return info

    def _finish(self, rest: str) -> None:
        if self._stepper is None or self._stepper.finished:
            return
        self._observe()
        from mjsafe import RunResult

        self.result = RunResult(self._stepper.finish(rest))
