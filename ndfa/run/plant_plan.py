"""What `ndfa plant` plants and where: a plan file (TOML), or placements drawn from a seed.

A plan lists objects; positions are (x, y) in metres in the source's world as `ndfa detect`
levels it (the positions its `--json` reports), on the support surface there:

    [[object]]                  # a real object of the recordings
    name = "white mug"
    real = true
    at = [-0.72, 1.80]
    radius = 0.08               # its region: a cylinder on the support (default 0.08 m, 0.20 m high)
    change = "removed"          # removed from the target | unchanged (default): listed in the truth

    [[object]]                  # a mesh put into the recordings
    mesh = "mug:3"              # the 3rd test-split procedural mug, or a mesh file (OBJ, PLY, STL, GLB)
    at = [0.10, 1.50]           # where it stands: in the source (moved, unchanged, removed) or target (added)
    to = [0.70, 1.50]           # moved: where it stands in the target
    change = "moved"            # added | removed | moved | unchanged
    yaw_deg = 30                # turned about up (default 0)
    color = [0.8, 0.2, 0.2]     # albedo in [0, 1] (default: one from the mesh's name)
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ndfa.core.errors import OptionError
from ndfa.sim.mug import Mug

CHANGES = ("added", "removed", "moved", "unchanged")
REAL_CHANGES = ("removed", "unchanged")
DEFAULT_RADIUS_M = 0.08
DEFAULT_HEIGHT_M = 0.20
# Auto placements: spots this far apart and from the real objects (a mug's footprint and a margin),
# a move's ends at least this far apart (where the surface allows).
APART_M = 0.25
MOVE_M = 0.50
CLEARANCE_M = 0.12  # plane all around a placed mesh, within this of its axis


@dataclass(frozen=True)
class PlantedObject:
    """One object of a plan. `source_xy` / `target_xy`: where it stands in each session (None: absent)."""

    name: str
    change: str
    real: bool
    source_xy: np.ndarray | None
    target_xy: np.ndarray | None
    radius_m: float = DEFAULT_RADIUS_M
    height_m: float = DEFAULT_HEIGHT_M
    mesh: str = ""
    yaw_deg: float = 0.0
    color: tuple[float, float, float] | None = None

    def xy(self, session: str) -> np.ndarray | None:
        return self.source_xy if session == "source" else self.target_xy

    def describe(self) -> str:
        def at(xy: np.ndarray | None) -> str:
            return "-" if xy is None else f"({xy[0]:.2f}, {xy[1]:.2f})"
        what = "real object" if self.real else self.mesh
        return f"{self.name} [{what}] {self.change}: source {at(self.source_xy)} -> target {at(self.target_xy)}"

    def as_dict(self) -> dict:
        return {"name": self.name, "change": self.change, "real": self.real, "mesh": self.mesh or None,
                "source_xy": None if self.source_xy is None else [float(v) for v in self.source_xy],
                "target_xy": None if self.target_xy is None else [float(v) for v in self.target_xy],
                "radius_m": self.radius_m, "height_m": self.height_m, "yaw_deg": self.yaw_deg}


def read_plan(path: Path) -> list[PlantedObject]:
    """The objects of the plan file `path`; OptionError naming the file and the entry when wrong."""
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as error:
        raise OptionError(f"--plan {path}: cannot be read ({error})") from None
    except tomllib.TOMLDecodeError as error:
        raise OptionError(f"--plan {path}: not valid TOML ({error})") from None
    entries = data.get("object", [])
    unknown = sorted(set(data) - {"object"})
    if unknown or not isinstance(entries, list):
        raise OptionError(f"--plan {path}: expected only [[object]] tables, got {', '.join(unknown) or 'object'}")
    return [_entry(path, position, entry) for position, entry in enumerate(entries)]


_KEYS = {"name", "real", "at", "to", "radius", "height", "change", "mesh", "yaw_deg", "color"}


def _entry(path: Path, position: int, entry: dict) -> PlantedObject:
    where = f"--plan {path}: object {position + 1}"
    if not isinstance(entry, dict):
        raise OptionError(f"{where}: must be a table")
    if unknown := sorted(set(entry) - _KEYS):
        raise OptionError(f"{where}: unknown key(s) {', '.join(unknown)}")
    real = entry.get("real", False)
    change = entry.get("change", "unchanged")
    if not isinstance(real, bool) or change not in (REAL_CHANGES if real else CHANGES):
        raise OptionError(f"{where}: change must be one of {', '.join(REAL_CHANGES if real else CHANGES)}, "
                          f"got {change!r}")
    at = _xy(where, "at", entry.get("at"))
    to = _xy(where, "to", entry.get("to")) if "to" in entry else None
    if (change == "moved") != (to is not None):
        raise OptionError(f"{where}: a moved object needs 'to' (where it stands in the target), others none")
    mesh = entry.get("mesh", "")
    if real == bool(mesh) or not isinstance(mesh, str):
        raise OptionError(f"{where}: give either real = true or a mesh (\"mug:N\" or a mesh file), not both")
    if mesh and not mesh.startswith("mug:"):
        mesh = str((path.parent / mesh).resolve())
    numbers = {}
    for key, default, low, high in (("radius", DEFAULT_RADIUS_M, 0.01, 1.0), ("height", DEFAULT_HEIGHT_M, 0.02, 2.0),
                                    ("yaw_deg", 0.0, -360.0, 360.0)):
        value = entry.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
            raise OptionError(f"{where}: {key} must be a number in [{low:g}, {high:g}], got {value!r}")
        numbers[key] = float(value)
    color = entry.get("color")
    if color is not None and not (isinstance(color, list) and len(color) == 3
                                  and all(isinstance(c, (int, float)) and 0 <= c <= 1 for c in color)):
        raise OptionError(f"{where}: color must be three numbers in [0, 1], got {color!r}")
    source = None if change == "added" else at
    target = to if change == "moved" else None if change == "removed" else at
    return PlantedObject(name=str(entry.get("name", f"object {position + 1}")), change=change, real=real,
                         source_xy=source, target_xy=target, radius_m=numbers["radius"],
                         height_m=numbers["height"], mesh=mesh, yaw_deg=numbers["yaw_deg"],
                         color=None if color is None else tuple(float(c) for c in color))


def _xy(where: str, key: str, value: object) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
        raise OptionError(f"{where}: {key} must be [x, y] in metres, got {value!r}")
    return np.array(value, dtype=float)


def load_mesh(spec: str) -> Mug:
    """The mesh a plan names: "mug:N" (the N-th test-split procedural mug: never seen in training)
    or a mesh file."""
    from ndfa.sim.mesh_io import load_mug_mesh
    from ndfa.sim.splits import make_split_mug

    if spec.startswith("mug:"):
        try:
            index = int(spec[4:])
        except ValueError:
            raise OptionError(f"mesh {spec!r}: expected mug:N with N a whole number") from None
        return make_split_mug("test", index)
    return load_mug_mesh(Path(spec))


def mesh_color(obj: PlantedObject) -> tuple[float, float, float]:
    """The object's albedo: its own, or one drawn from its name (the same name, the same colour)."""
    if obj.color is not None:
        return obj.color
    rng = np.random.default_rng(list(obj.name.encode()) or [0])
    return tuple(float(c) for c in rng.uniform(0.2, 0.9, size=3))


def auto_plan(real: list[PlantedObject], spots: np.ndarray, seed: int) -> list[PlantedObject]:
    """The seed's placements: one of the real objects removed (the others kept), one procedural
    mug moved (at least `MOVE_M` between its ends when the spots allow) and one added, on `spots`
    (K, 2: free places on a support surface both sessions saw)."""
    rng = np.random.default_rng([seed, 29])
    avoid = np.array([o.source_xy for o in real]).reshape(-1, 2)
    chosen = None if len(spots) == 0 else _choose(spots, rng, avoid)
    if chosen is None:
        raise OptionError(f"--auto: no room for three objects {APART_M:.2f} m apart on the largest support "
                          f"surface both recordings saw ({len(spots)} free spots)")
    plan = list(real)
    if real:
        removed = int(rng.integers(len(real)))
        plan[removed] = PlantedObject(real[removed].name, "removed", True, real[removed].source_xy, None,
                                      real[removed].radius_m, real[removed].height_m)
    mugs = rng.choice(1000, size=2, replace=False)
    yaws = rng.uniform(-180.0, 180.0, size=2)
    plan.append(PlantedObject(f"mug:{mugs[0]} moved", "moved", False, chosen[0], chosen[1], mesh=f"mug:{mugs[0]}",
                              yaw_deg=float(yaws[0])))
    plan.append(PlantedObject(f"mug:{mugs[1]} added", "added", False, None, chosen[2], mesh=f"mug:{mugs[1]}",
                              yaw_deg=float(yaws[1])))
    return plan


def _choose(spots: np.ndarray, rng: np.random.Generator, avoid: np.ndarray) -> np.ndarray | None:
    from ndfa.sim.plant_place import choose_spots

    return choose_spots(spots, 3, rng, APART_M, avoid, first_pair_apart_m=MOVE_M)
