"""The residual forest's sidecar: ``MODEL.residual.npz`` beside the model file.

Forest arrays are data, never pickles; the model file names the sidecar with
its sha256, so a model file and a forest of another fit cannot be paired.
"""

from __future__ import annotations

import hashlib
import io
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from compd.errors import ModelError, ModelFileError
from compd.model.residual import Forest

if TYPE_CHECKING:
    from compd.files.modelschema import ModelDoc

#: Forest arrays stored per output, as ``<output>/<name>`` in the sidecar.
FOREST_ARRAYS = ("roots", "left", "right", "feature", "threshold", "value")


def sidecar_path(model_path: str | Path) -> Path:
    """``MODEL.yaml`` -> ``MODEL.residual.npz`` in the same folder."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.stem + ".residual.npz")


def sidecar_bytes(forests: Mapping[str, Forest]) -> bytes:
    """The ``.npz`` content holding each output's forest arrays (``<output>/<array>``)."""
    arrays: dict[str, np.ndarray] = {}
    for output, forest in forests.items():
        for name in FOREST_ARRAYS:
            arrays[f"{output}/{name}"] = getattr(forest, name)
        arrays[f"{output}/n_features"] = np.array(forest.n_features)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def load_sidecar(model_path: str | Path, file: str, sha256: str, output: str) -> Forest:
    """Read ``output``'s forest from the sidecar ``file`` (relative to the model file), hash checked."""
    path = Path(model_path).parent / file
    fix = "Keep the .npz written by compd fit next to the model file, or refit the model"
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ModelFileError(
            model_path,
            f"residual-model file {str(path)!r} cannot be read ({exc.strerror})",
            where=f"outputs.{output}.residual.file",
            fix=fix,
        ) from exc
    actual = hashlib.sha256(raw).hexdigest()
    if actual != sha256:
        raise ModelFileError(
            model_path,
            f"residual-model file {str(path)!r} has sha256 {actual[:12]}..., the model file "
            f"names {sha256[:12]}...: the forest belongs to another model",
            where=f"outputs.{output}.residual.sha256",
            fix=fix,
        )
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            arrays = {name: npz[f"{output}/{name}"] for name in FOREST_ARRAYS}
            n_features = int(npz[f"{output}/n_features"])
        return Forest(
            roots=arrays["roots"].astype(np.intp),
            left=arrays["left"].astype(np.intp),
            right=arrays["right"].astype(np.intp),
            feature=arrays["feature"].astype(np.intp),
            threshold=arrays["threshold"].astype(float),
            value=arrays["value"].astype(float),
            n_features=n_features,
        )
    except (KeyError, ValueError, OSError, ModelError) as exc:
        raise ModelFileError(
            model_path,
            f"residual-model file {str(path)!r} holds no valid forest for {output!r} ({exc})",
            where=f"outputs.{output}.residual.file",
            fix=fix,
        ) from exc


def copy_sidecars(files: Iterable[str], parent_path: str | Path, out_path: str | Path) -> None:
    """A derived model's residual sidecars ``files`` (as the parent names them) beside ``out_path``.

    A model derived from a stacked one (``compd update``, ``compd extend``,
    ``compd model export --updated``) names its parent's forests: written
    elsewhere without them, it could not be loaded.
    """
    for file in files:
        source = Path(parent_path).parent / file
        target = Path(out_path).parent / file
        if source.resolve() != target.resolve():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, target)


def residual_files(doc: ModelDoc) -> list[str]:
    """The sidecar files a model file names (one per output with a residual forest)."""
    return [o.residual.file for o in doc.outputs.values() if o.residual is not None]
