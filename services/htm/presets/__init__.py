"""Named configuration presets (YAML files loaded with ``--config``).

``dissertation.yaml`` (:data:`DISSERTATION_PRESET`): Table 4.1 values for every field whose
PoseidonSLAM default is ours (docs/DECISIONS.md, "Defaults that are ours").
"""
from pathlib import Path

DISSERTATION_PRESET = Path(__file__).resolve().parent / "dissertation.yaml"
