"""A train state as a checkpoint holds it: one flat host array per dtype, the layout that
names each array (path, shape, dtype, PRNG key or not), and a CRC-32 of every array.

Pure functions over pytrees and host arrays, without orbax: :mod:`mjx_emp.run.checkpoint`
writes and reads what they make.
"""

from __future__ import annotations

import dataclasses
import zlib
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjx_emp.errors import CheckpointError


def _is_key(leaf: Any) -> bool:
    return jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key)


def layout_of(tree: Any) -> list[dict]:
    """Each array's path, shape, dtype and whether it is a PRNG key (stored as its key data).

    Works on arrays and on ``jax.eval_shape`` structs alike, so a config's layout is known
    without building its state.
    """
    layout = []
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        key = _is_key(leaf)
        if key:
            leaf = jax.eval_shape(jax.random.key_data, leaf)
        layout.append({"path": jax.tree_util.keystr(path), "shape": list(leaf.shape),
                       "dtype": np.dtype(leaf.dtype).name, "key": key})
    return layout


def pack(tree: Any) -> dict[str, np.ndarray]:
    """Host copy of a pytree as one flat array per dtype, in ``layout_of`` order.

    A few large arrays write far faster than hundreds of small ones (orbax pays about a
    millisecond per array), and the copy is taken now, so the device buffers may be donated
    while the write finishes in the background. PRNG keys go in as their raw key data; dtype
    groups with no elements are left out (orbax refuses zero-size arrays).
    """
    groups: dict[str, list[np.ndarray]] = {}
    for leaf in jax.tree.leaves(tree):
        if _is_key(leaf):
            leaf = jax.random.key_data(leaf)
        host = np.asarray(leaf)
        groups.setdefault(host.dtype.name, []).append(host.ravel())
    packed = {name: np.concatenate(parts) for name, parts in groups.items()}  # concatenate copies
    return {name: array for name, array in packed.items() if array.size}


def digest(array: np.ndarray) -> int:
    """CRC-32 of an array's bytes."""
    return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1))


def array_digests(packed: dict[str, np.ndarray], layout: list[dict]) -> dict[str, int]:
    """:func:`digest` of every array, by layout path: written with each checkpoint so that a
    restore notices bytes that changed on disk (a flipped bit reads back without error)."""
    return {path: digest(array) for path, array in arrays_by_path(packed, layout).items()}


def data_files(item_dir: Path) -> list[str]:
    """The files under a checkpoint item's directory (where its arrays' bytes lie)."""
    return sorted(str(p) for p in Path(item_dir).rglob("*") if p.is_file())


def packed_shapes(layout: list[dict]) -> dict[str, jax.ShapeDtypeStruct]:
    """The flat per-dtype arrays that ``pack`` makes for a state of this layout."""
    sizes: dict[str, int] = {}
    for entry in layout:
        sizes[entry["dtype"]] = sizes.get(entry["dtype"], 0) + int(np.prod(entry["shape"]))
    return {name: jax.ShapeDtypeStruct((size,), np.dtype(name)) for name, size in sizes.items() if size}


def unpack(packed: dict[str, Any], template: Any) -> Any:
    """Inverse of ``pack``: ``template`` (a state or its ``jax.eval_shape``) gives the structure."""
    layout = layout_of(template)
    return tree_from_arrays(arrays_by_path(packed, layout), template, layout)


def tree_from_arrays(arrays: dict[str, np.ndarray], template: Any, layout: list[dict]) -> Any:
    """The pytree of ``template``'s structure (``layout`` is its layout) from one host array
    per path; PRNG keys are wrapped back from their key data."""
    leaves, treedef = jax.tree.flatten(template)
    rebuilt = []
    for like, entry in zip(leaves, layout):
        value = jnp.asarray(arrays[entry["path"]])
        if entry["key"]:
            impl = jax.random.key_impl(like) if isinstance(like, jax.Array) else None
            value = jax.random.wrap_key_data(value, impl=impl)
        rebuilt.append(value)
    return jax.tree.unflatten(treedef, rebuilt)


def arrays_by_path(packed: dict[str, Any], layout: list[dict]) -> dict[str, np.ndarray]:
    """Split ``pack``'s flat per-dtype arrays back into one host array per layout path."""
    offsets = dict.fromkeys(packed, 0)
    arrays = {}
    for entry in layout:
        size = int(np.prod(entry["shape"]))
        start = offsets.get(entry["dtype"], 0)
        flat = np.asarray(packed[entry["dtype"]])[start:start + size] if size else np.zeros(0, entry["dtype"])
        offsets[entry["dtype"]] = start + size
        arrays[entry["path"]] = flat.reshape(entry["shape"])
    return arrays


LEFT_OUT = "left_out"
"""The digests item's key listing the state fields a checkpoint was written without."""


def left_out_of(digests: dict | None) -> list[str]:
    """The state fields a checkpoint's digests item says were not written (empty for a whole state,
    or for a checkpoint older than digests)."""
    return list((digests or {}).get(LEFT_OUT, []))


def verify_digests(step_dir: Path, arrays: dict[str, np.ndarray], written: dict | None) -> None:
    """Check every restored array of ``step_dir`` against the digests written with it (None:
    a checkpoint written without digests, whose arrays are not checked)."""
    if written is None:
        return
    for path, expected in written["arrays"].items():
        found = digest(arrays[path]) if path in arrays else None
        if found != expected:
            raise CheckpointError(
                f"{step_dir}: array {path} does not match the checksum written with it (crc32 "
                f"{found if found is None else format(found, '08x')}, written {expected:08x}): the checkpoint "
                f"changed on disk; its bytes lie in {', '.join(data_files(step_dir / 'state'))}"
            )


def without_fields(state: Any, fields: tuple[str, ...]) -> Any:
    """``state`` (a dataclass pytree) with ``fields`` set to None, so that they hold no arrays;
    the other arrays keep their paths."""
    return dataclasses.replace(state, **dict.fromkeys(fields)) if fields else state


def with_zeros_for(arrays: dict[str, np.ndarray], expected: list[dict], fields: list[str]) -> dict[str, np.ndarray]:
    """``arrays`` plus zeros for every array of ``expected`` that lies under one of ``fields``
    (the fields a checkpoint was written without): empty replays, environments never stepped."""
    if not fields:
        return arrays
    heads = tuple(f".{field}{after}" for field in fields for after in (".", "["))
    filled = dict(arrays)
    for entry in expected:
        path = entry["path"]
        if path not in arrays and (path.startswith(heads) or path in {f".{field}" for field in fields}):
            filled[path] = np.zeros(entry["shape"], np.dtype(entry["dtype"]))
    return filled


def layout_in_order(arrays: dict[str, np.ndarray], expected: list[dict]) -> list[dict]:
    """The layout of ``arrays`` in ``expected``'s order, a missing path marked as such and
    paths ``expected`` lacks appended, so :func:`layout_mismatch` can compare the two."""
    known = {entry["path"] for entry in expected}
    found = [{**entry, "shape": list(arrays[entry["path"]].shape), "dtype": arrays[entry["path"]].dtype.name}
             if entry["path"] in arrays else {**entry, "shape": "(missing)"} for entry in expected]
    return found + [{"path": path, "shape": list(value.shape), "dtype": value.dtype.name, "key": False}
                    for path, value in arrays.items() if path not in known]


def layout_mismatch(saved: list[dict], expected: list[dict]) -> str | None:
    """The first array whose path, shape or dtype differs between two layouts, or None."""
    for have, want in zip(saved, expected):
        if have != want:
            return f"array {have['path']} is {have['shape']} {have['dtype']}, expected {want['shape']} {want['dtype']}"
    if len(saved) != len(expected):
        return f"{len(saved)} arrays, expected {len(expected)}"
    return None
