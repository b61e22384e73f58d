"""Say in words when a design cannot determine a model's terms (relative singular values).

A small module for `accelcal diagnose`; issue 11 adds identifiability to `accelcal fit`,
and the two are meant to be merged into one.
"""
from __future__ import annotations

import numpy as np

REL_SV_MIN = 1e-6  # a relative singular value below this: the terms along its vector are not determined


def distinct_orientations(ref: np.ndarray) -> int:
    u = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    return len(np.unique(np.round(u, 3), axis=0))


def describe_design(data, effects) -> dict:
    """Distinct orientations, relative singular values of the column-scaled static design (on ideal
    readings g = ref, or unit readings without references), and which terms are confounded."""
    from .gap_effects import static_design

    ideal = data.ref if data.ref is not None else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    dh = np.zeros((data.P, 2)) if "drift" in effects else None
    A, _, _, labels = static_design(set(effects), ideal, data.ref, dT, dh, data.ref is None, data.n_temps)
    n_or = distinct_orientations(ideal)
    out = {"distinct_orientations": n_or, "poses": data.P, "parameters": len(labels)}
    if not labels:
        return {**out, "text": f"{n_or} distinct orientations; no fitted terms"}
    M = A.reshape(-1, A.shape[-1])
    sc = np.linalg.norm(M, axis=0)
    sc = np.where(sc > 0, sc, 1.0)
    _, s, Vt = np.linalg.svd(M / sc, full_matrices=False)
    rel = s / s[0]
    out["relative_singular_values"] = rel.tolist()
    bad = np.flatnonzero(rel < REL_SV_MIN)
    if not bad.size:
        out["text"] = (f"{n_or} distinct orientations determine all {len(labels)} terms "
                       f"(smallest relative singular value {rel[-1]:.2g})")
        return out
    groups = []
    for k in bad:
        v = np.abs(Vt[k]) / np.max(np.abs(Vt[k]))
        groups.append([f"{e} {d}" for (e, d), x in zip(labels, v) if x > 0.2])
    out["confounded"] = groups
    out["text"] = (f"{n_or} distinct orientations cannot determine {len(bad)} combination(s) of the "
                   f"{len(labels)} terms: " + "; ".join(" with ".join(g) for g in groups)
                   + f" (relative singular value {rel[bad[0]]:.1g})")
    return out
