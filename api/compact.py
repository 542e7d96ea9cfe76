"""Compact, lossless storage of plan documents: float arrays as byte-shuffled binary, then Zstandard.

A result document is mostly sampled series (time, and position, velocity, acceleration, effort and
joint values of every drive at every controller period): thousands of float64 numbers written as
17-digit decimal text. Stored as text that is about 20 bytes a number; here each float array becomes
its IEEE-754 bytes (8 a number, exact), *shuffled* so that byte k of every number is stored together
(the sign/exponent bytes of a smooth series are nearly constant and compress to almost nothing, the
same trick as the HDF5/Blosc shuffle filter), and the whole blob is compressed with Zstandard (format 3,
level 3). Earlier versions wrote format 2 (zlib level 1) and format 1 (LZMA); both are still read.
Measured on hatch-bay-insert's 2.1 MB of shuffled samples (``bench/``-free figures from this module's
choice, one machine): zlib level 1 21 ms to 1.27 MB, Zstandard level 3 4.3 ms to 1.15 MB (and 1 ms
instead of 6 ms to read back); LZMA about a second. The write is on a job worker's critical path.

:func:`pack_value` packs the document as the worker made it (a dict, never written as text);
:func:`pack_document` packs its JSON text. :func:`unpack_document` is their exact inverse (every float bit
for bit, ints stay ints). :func:`unpack_text` writes the document as compact JSON with orjson straight
from the unpacked arrays (no Python float per sample: 20-30x faster than ``json.dumps`` of the lists, the
server's largest cost per finished plan): the same JSON value as ``json.dumps(doc)``, each float in its
shortest round-trip form, non-finite floats as ``null`` (planner documents hold none).
Only lists whose items are all ``float`` (1-D) or equal-length lists of ``float`` (2-D) are packed;
ints, bools, strings and ragged lists stay in the JSON skeleton as they are, so their text is unchanged.
"""

from __future__ import annotations

import json
import lzma
import struct
import zlib
from itertools import chain
from typing import Any

import numpy as np
import orjson
import zstandard

#: First bytes of a packed document (format version 3: Zstandard).
MAGIC = b"CPD3"
#: First bytes of format version 2 (zlib), written by earlier versions.
MAGIC_V2 = b"CPD2"
#: First bytes of format version 1 (LZMA), written by earlier versions.
MAGIC_V1 = b"CPD1"
#: Zstandard level of format 3: level 1 is 2.4 ms for 1.27 MB on the plan above, level 3 4.3 ms for
#: 1.15 MB (10% less), higher levels cost several times more for a few per cent.
ZSTD_LEVEL = 3
#: Key of the placeholder that stands for an array in the skeleton (never a key of a planner document).
ARRAY_KEY = "\x00array"
#: Shorter float lists stay in the skeleton (not worth a placeholder).
MIN_PACKED_FLOATS = 16


def _float_array(value: list[Any]) -> np.ndarray[Any, np.dtype[np.float64]] | None:
    """``value`` as a float64 array when it is a 1-D list of floats or a 2-D list of float rows."""
    if len(value) == 0:
        return None
    types = set(map(type, value))  # exact types (a bool or an int is not a float), counted at C speed
    if types == {float}:
        return np.array(value, dtype=np.float64) if len(value) >= MIN_PACKED_FLOATS else None
    if types == {list}:
        width = len(value[0])
        if width == 0 or len(value) * width < MIN_PACKED_FLOATS:
            return None
        if set(map(len, value)) == {width} and set(map(type, chain.from_iterable(value))) == {float}:
            return np.array(value, dtype=np.float64)
    return None


def _shuffle(a: np.ndarray[Any, np.dtype[np.float64]]) -> bytes:
    """Bytes of ``a`` (little-endian float64), byte k of every number stored together."""
    le = np.ascontiguousarray(a.reshape(-1), dtype="<f8")
    return np.ascontiguousarray(le.view(np.uint8).reshape(-1, 8).T).tobytes()


def _unshuffle(data: bytes, shape: tuple[int, ...]) -> np.ndarray[Any, np.dtype[np.float64]]:
    n = int(np.prod(shape)) if shape else 1
    planes = np.frombuffer(data, dtype=np.uint8).reshape(8, n)
    return np.ascontiguousarray(planes.T).view("<f8").reshape(shape).astype(np.float64)


def pack_document(text: str) -> bytes:
    """Pack a JSON document (text as written by ``json.dumps``) into the compact binary form."""
    return pack_value(json.loads(text))


def pack_value(document: Any) -> bytes:
    """Pack a document (the value ``json.dumps`` would write) into the compact binary form.

    A float numpy array (1-D or 2-D) in the document is packed as its ``tolist()`` would be (the same
    blob), without making the list: the worker's documents keep their samples as arrays
    (:func:`planner.documents.output.result_document` with ``arrays=True``); other arrays go in as lists.
    """
    arrays: list[np.ndarray[Any, np.dtype[np.float64]]] = []

    def walk(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: walk(v) for k, v in value.items()}
        if isinstance(value, np.ndarray):  # as its list would be packed, without making the list
            arr = value.astype(np.float64, copy=False) if value.dtype.kind == "f" else None
            if arr is None or arr.ndim not in (1, 2) or 0 in arr.shape or arr.size < MIN_PACKED_FLOATS:
                return walk(value.tolist())
            arrays.append(arr)
            return {ARRAY_KEY: len(arrays) - 1}
        if isinstance(value, list):
            arr = _float_array(value)
            if arr is not None:
                arrays.append(arr)
                return {ARRAY_KEY: len(arrays) - 1}
            return [walk(v) for v in value]
        return value

    skeleton = walk(document)
    header = json.dumps(
        {"doc": skeleton, "arrays": [list(a.shape) for a in arrays]}, separators=(",", ":")
    ).encode("utf-8")
    body = header + b"".join(_shuffle(a) for a in arrays)
    return MAGIC + struct.pack("<I", len(header)) + zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(body)


def unpack_document(blob: bytes) -> Any:
    """The document (parsed JSON value) of a packed blob.

    Raises:
        ValueError: not a packed document of this format.
    """
    return _unpack(blob, lists=True)


def _unpack(blob: bytes, lists: bool) -> Any:
    """The document of a packed blob, its arrays as lists (``lists``) or as float64 numpy arrays."""
    magic = blob[:4]
    if magic not in (MAGIC, MAGIC_V2, MAGIC_V1):
        raise ValueError("not a packed cabinplan document")
    (n_header,) = struct.unpack("<I", blob[4:8])
    if magic == MAGIC:
        body = zstandard.ZstdDecompressor().decompress(blob[8:])
    else:
        body = zlib.decompress(blob[8:]) if magic == MAGIC_V2 else lzma.decompress(blob[8:])
    header = json.loads(body[:n_header])
    arrays: list[Any] = []
    offset = n_header
    for shape in header["arrays"]:
        size = 8 * int(np.prod(shape))
        array = _unshuffle(body[offset : offset + size], tuple(shape))
        arrays.append(array.tolist() if lists else array)
        offset += size

    def walk(value: Any) -> Any:
        if isinstance(value, dict):
            if len(value) == 1 and ARRAY_KEY in value:
                return arrays[int(value[ARRAY_KEY])]
            return {k: walk(v) for k, v in value.items()}
        if isinstance(value, list):
            return [walk(v) for v in value]
        return value

    return walk(header["doc"])


def unpack_json(blob: bytes) -> bytes:
    """The document as compact JSON, UTF-8 bytes (orjson; see the module docstring)."""
    try:
        return orjson.dumps(_unpack(blob, lists=False), option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:  # a value orjson cannot write (an integer beyond 64 bits): the standard library can
        return json.dumps(_unpack(blob, lists=True), separators=(",", ":")).encode()


def unpack_text(blob: bytes) -> str:
    """The document as compact JSON text (:func:`unpack_json`, decoded)."""
    return unpack_json(blob).decode()


_SCALARS = {float, int, str, bool, type(None)}


def document_json(document: Any) -> bytes | None:
    """The JSON :func:`unpack_json` gives for ``pack_value(document)``, written from the document itself.

    The worker sends it with the packed blob (bytes: no str to encode, pickle and decode on the way), so
    the server answers a finished job's first read without unpacking it (a 3-5 MB plan: about 10-25 ms of
    the server's CPU there, 5-7 ms here). The same orjson call on the same values: the skeleton's numbers
    as JSON reads them back (ints stay ints, floats round-trip) and the packed arrays as float64, so the
    text is the same, byte for byte (tested on arrays of every kind and on a served plan). ``None`` for
    a document orjson cannot write (an integer beyond 64 bits): the server then unpacks the stored blob.
    """

    def normal(value: Any) -> Any:  # arrays as unpacking gives them: float64, C order; others as lists
        if isinstance(value, dict):
            return {k: normal(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            if set(map(type, value)) <= _SCALARS:  # a plain series (counted at C speed): as it is
                return value
            return [normal(v) for v in value]
        if isinstance(value, np.ndarray):
            if value.dtype.kind == "f" and value.ndim in (1, 2):
                return np.ascontiguousarray(value, dtype=np.float64)
            return value.tolist()
        return value

    try:
        return orjson.dumps(normal(document), option=orjson.OPT_SERIALIZE_NUMPY)
    except TypeError:
        return None


__all__ = [
    "MAGIC",
    "MAGIC_V1",
    "MAGIC_V2",
    "document_json",
    "pack_document",
    "pack_value",
    "unpack_document",
    "unpack_json",
    "unpack_text",
]
