"""`accelcal diagnose`'s question of any model of the effects catalog: ``describe_terms`` takes the static
design of those effects (built by diagnosis.effects.design.describe_design on ideal readings), and names the
terms along every relative singular value below ``TERM_REL_SV_MIN`` (confounded: no data of this design can
separate them)."""
from __future__ import annotations

from typing import NotRequired, TypedDict

import numpy as np

from .orientations import first_of_orientation

TERM_REL_SV_MIN = 1e-6  # describe_terms: terms along a smaller relative singular value are not determined


class TermsCounts(TypedDict):
    """How many distinct orientations, poses and fitted terms a design has."""

    distinct_orientations: int
    poses: int
    parameters: int


class TermsDescription(TermsCounts):
    """What ``describe_terms`` finds (diagnose --json ``identifiability``; key order as declared)."""

    relative_singular_values: NotRequired[list[float]]  # absent without fitted terms
    confounded: NotRequired[list[list[str]]]  # the terms of each undetermined combination
    text: str


def describe_terms(A: np.ndarray, labels: list[tuple[str, str]], ideal: np.ndarray) -> TermsDescription:
    """Distinct orientations of ``ideal`` (P, 3), relative singular values of the column-scaled
    design ``A`` (..., n_terms) whose columns are ``labels`` ((effect, detail) pairs), and which
    terms are confounded; the text says it in words (diagnose's untestable reasons)."""
    n_or = int(first_of_orientation(ideal[None])[0].sum())
    counts: TermsCounts = {"distinct_orientations": n_or, "poses": len(ideal), "parameters": len(labels)}
    if not labels:
        return {**counts, "text": f"{n_or} distinct orientations; no fitted terms"}
    M = A.reshape(-1, A.shape[-1])
    sc = np.linalg.norm(M, axis=0)
    _, s, Vt = np.linalg.svd(M / np.where(sc > 0, sc, 1.0), full_matrices=False)
    rel = s / s[0]
    bad = np.flatnonzero(rel < TERM_REL_SV_MIN)
    if not bad.size:
        return {**counts, "relative_singular_values": rel.tolist(),
                "text": (f"{n_or} distinct orientations determine all {len(labels)} terms "
                         f"(smallest relative singular value {rel[-1]:.2g})")}
    groups = []
    for k in bad:
        v = np.abs(Vt[k]) / np.max(np.abs(Vt[k]))
        groups.append([f"{e} {d}" for (e, d), x in zip(labels, v, strict=True) if x > 0.2])
    return {**counts, "relative_singular_values": rel.tolist(), "confounded": groups,
            "text": (f"{n_or} distinct orientations cannot determine {len(bad)} combination(s) of the "
                     f"{len(labels)} terms: " + "; ".join(" with ".join(g) for g in groups)
                     + f" (relative singular value {rel[bad[0]]:.1g})")}
