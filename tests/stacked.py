"""A stacked model's forest as the tests write it: the sidecar beside the model file and its YAML block."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

from compd.files.modelschema import ResidualDoc
from compd.files.sidecar import sidecar_bytes, sidecar_path
from compd.model.residual import ResidualModel


def forest_beside(model_path: Path, residual: ResidualModel, **block: Any) -> ResidualDoc:
    """Write ``residual``'s forest beside ``model_path`` (for output disp_z_um); the block naming
    it with its sha256 (``block``: further keys, e.g. ``trees``)."""
    sidecar = sidecar_bytes({"disp_z_um": residual.forest})
    sidecar_path(model_path).write_bytes(sidecar)
    return ResidualDoc(
        signal="door_open",
        time_constants_s=list(residual.features.time_constants_s),
        file=sidecar_path(model_path).name,
        sha256=hashlib.sha256(sidecar).hexdigest(),
        **block,
    )
