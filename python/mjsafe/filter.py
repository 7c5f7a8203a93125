"""What a filter written in Python receives (docs/python.md, "What a filter sees").

``filter_channel(self, t, channel, state, nominal, constraints, **keywords)`` gets these
keyword arguments when it names them (or takes ``**kwargs``), and ``issued_law`` gets
``barriers`` and ``vehicle`` the same way. The dicts are plain ``dict`` objects; these
``TypedDict`` classes document their keys and let a type checker check a filter.
"""

from __future__ import annotations

from typing import Any, Literal, TypedDict

import numpy as np
import numpy.typing as npt

__all__ = ["Queue", "Barrier", "Vehicle", "Footprint", "Circle"]


class Queue(TypedDict):
    """One channel's delay queue (``queues[i]`` is channel i, in ``vehicle["channels"]`` order)."""

    channel: str
    """The channel's name."""
    delay: float
    """Its delay at t (s)."""
    initial: float
    """The input applied before the first issued command arrives ((4.79)/(4.80))."""
    issued: npt.NDArray[np.float64]
    """(issue time s, value) rows, oldest first, before this tick's: the commands that may still
    apply (the one in force at t included)."""


class Barrier(TypedDict, total=False):
    """One barrier the controller knows at the decision, as it sees it at the evaluation time.

    Always present: ``name``, ``obstacle``, ``moving``, ``shape``, ``rows``. The others depend
    on ``shape``:

    - ``ball``: h = ‖x_S − c‖² − r² (``inside``: r² − ‖x_S − c‖²) with S = ``indices``
      ((4.81): a circular obstacle, S the planar position), ``centre`` c, ``radius`` r (m; the
      obstacle's radius plus the vehicle's hull radius).
    - ``body_circle``: the same for the vehicle's covering circle at ``offset`` (m, along and
      across the heading): q = p + R(θ)·offset, ``centre``, ``radius`` (both circles' radii).
    - ``half_space``: h = ``coefficients``·x + ``offset``.
    - ``quadratic``: h = xᵀ``q``x + ``c``·x + ``d``.
    - ``body_half_space``: h = ``normal``·q + ``distance`` for the covering circle at ``offset``
      (a road's line edge).
    - ``body_curve``: h = ``side``·e(q) − ``margin``, e the signed distance from q to the smooth
      curve through ``points`` (a polyline road edge).
    - ``headway``: h = (``lead`` − ``rear`` − p) − ``standstill`` − ``time_headway``·v (car following).

    A moving actor's ``centre`` (``lead`` for a headway) is where the controller assumes it at
    the evaluation time (``actor_knowledge``: what the Rust filters' rows use), with its
    ``velocity`` and ``acceleration`` (m/s, m/s²).
    """

    name: str
    obstacle: str
    """The obstacle it belongs to (the name before ``/``: a box's covering circles are
    ``<obstacle>/<i>-<j>``), or the barrier's own name."""
    moving: bool
    shape: Literal["ball", "body_circle", "half_space", "quadratic", "body_half_space", "body_curve", "headway"]
    rows: list[int]
    """The indices in ``constraints`` of its conditions at this decision: none for a road user
    out of reach or a filter without ``barrier_form``; two for a mixed-relative-degree barrier."""
    indices: list[int]
    centre: list[float]
    radius: float
    inside: bool
    offset: Any
    coefficients: list[float]
    q: list[list[float]]
    c: list[float]
    d: float
    normal: list[float]
    distance: float
    points: list[list[float]]
    side: float
    margin: float
    lead: float
    rear: float
    standstill: float
    time_headway: float
    velocity: list[float]
    acceleration: list[float]


class Circle(TypedDict):
    offset: list[float]
    """Its centre in the body frame (m, along and across the heading)."""
    radius: float


class Footprint(TypedDict):
    length: float
    width: float
    offset: float
    """How far the rectangle's centre lies ahead of the reference point (m)."""
    circles: list[Circle]
    """The covering circles, rear to front."""


class Vehicle(TypedDict):
    """The same dict at every call of a run."""

    kind: str
    states: list[str]
    """The state's components, in the order of ``state``."""
    channels: list[str]
    """The input channels, in the order of ``nominal``, ``b`` and ``queues``."""
    parameters: dict[str, float]
    """The analytic model's scalar parameters, e.g. ``{"wheelbase": 6.0}`` (m) for the bicycle (4.78)."""
    hull_radius: float
    footprint: Footprint | None
    initial_state: list[float]
    timestep: float
    """The plant step h (s)."""

