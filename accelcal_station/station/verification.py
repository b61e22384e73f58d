"""Which poses verify a calibration, and what each choice proves (docs/capture.md, "Verification").

``verify.mode: fit-poses`` (the default): fresh captures, taken after the fit, at the last
``verify.poses`` poses the jig presented for the fit, newest first, so the first needs no jig
move (the board is still where the last fit pose left it) and each further one is one step back
along the path the jig already took.  ``independent``: the design's own first poses (or
``verify.design``'s), each presented as a move of its own.

Both check the same chain on fresh samples: the calibration applied to counts the fit never saw
reads the expected output within ``acceptance.verify_error_max_mg``, and after the burn the
calibration read back from NVM gives the same output on those counts (the NVM round trip and the
applied calibration).  Only ``independent`` poses away from the fit's also test generalisation to
orientations the fit did not use; at a fit pose the check cannot see an error the fit absorbed at
that pose (e.g. a jig angle error the calibration learned), only noise, drift since the fit, a
wrong calibration or a wrong write.  The acceptance's cross-validation (leave-one-pose-out RMS,
``crossval_rms_mg``) is the generalisation check on every run, which is why fit-poses is the
throughput default.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..config.schema import VerifySection
from ..errors import ConfigError
from ..fixtures.base import PoseSpec
from ..fixtures.designs import get_design


@dataclass(frozen=True)
class VerificationPoses:
    """The poses to verify at, in order; whether the first needs a jig move; the mode that chose them."""

    mode: str
    poses: list[PoseSpec]
    first_moves: bool


def verify_mode(section: VerifySection | None) -> str:
    """verify.mode, with verify.design alone meaning independent poses (it names poses of its own)."""
    ver = section or VerifySection()
    if ver.design is not None:
        if "mode" in ver.model_fields_set and ver.mode == "fit-poses":
            raise ConfigError("verify.mode: fit-poses verifies at the fit's own poses, so verify.design cannot "
                              "be used with it; allowed: verify.mode: independent, or remove verify.design")
        return "independent"
    return ver.mode


def verification_poses(n: int, section: VerifySection | None, design: str, presented: list[PoseSpec]
                       ) -> VerificationPoses:
    """The ``n`` verification poses (StationConfig.verify_poses) for a board of plan design ``design`` whose
    fit poses the jig presented in order ``presented``; ``section``: the config's verify section."""
    mode = verify_mode(section)
    if n == 0:
        return VerificationPoses(mode, [], False)
    if mode == "fit-poses" and presented:
        return VerificationPoses(mode, list(reversed(presented))[:n], False)
    own = section.design if section is not None else None
    return VerificationPoses("independent", get_design(own or design)[:n], True)
