"""``poseidon run --map-dir DIR``: where a run loads its persisted state from and saves it to,
so that successive missions build one map (multi-session)."""
from __future__ import annotations

from pathlib import Path

from system.config import PoseidonConfig

__all__ = ["MAP_DIR_FILES", "use_map_dir"]


#: the files of a map directory (``poseidon run --map-dir DIR``) and the setting each one is
MAP_DIR_FILES = {
    "htm.state_path": "htm_state.npz",                               # SP/TM/LVC prototypes, sequence memory
    "posecells.state_path": "posecells.npz",                         # pose cells, LVC associations, gates
    "expmap.map_path": "expmap.npz",                                 # the experience map with its sessions
    "encoder.embedding_norm.path": "embnorm_{backbone}_{modality}.npz",  # embedding statistics per modality
}


def use_map_dir(config: PoseidonConfig, map_dir: str | Path) -> dict[str, str]:
    """Point every persisted state of ``config`` into ``map_dir`` (created if missing) and make
    a loaded experience map begin a new session (``expmap.sessions.begin_on_load``) in a new odometry
    frame (``posecells.state_new_odometry_frame``: the loaded pose cells keep their activity and
    associations, not the other mission's odometry): a run loads what is there at start and
    saves the merged state there at the end.  Returns the settings made."""
    d = Path(map_dir)
    if d.exists() and not d.is_dir():
        raise ValueError(f"--map-dir {d}: exists and is not a directory")
    d.mkdir(parents=True, exist_ok=True)
    made = {}
    for dotted, name in MAP_DIR_FILES.items():
        *path, field_name = dotted.split(".")
        setattr(config.get(".".join(path)), field_name, str(d / name))
        made[dotted] = str(d / name)
    config.expmap.sessions.begin_on_load = True
    made["expmap.sessions.begin_on_load"] = "true"
    config.posecells.state_new_odometry_frame = True
    made["posecells.state_new_odometry_frame"] = "true"
    return made
