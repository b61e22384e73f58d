"""The operator's language: operator-facing text (terminal prompts, the operator page, the verdict
reasons an operator reads) comes from gettext message catalogs, `station.language` in the config.

English is the source text (msgid); German ships as ``locale/de/LC_MESSAGES/accelcal-operator.po``
and its compiled ``.mo`` (``msgfmt -o ...mo ...po``; tests/test_i18n.py checks they agree).
Engineers' output (``--json``, the event log, error lines) stays English and never passes here.

Foundation layer: imports only the standard library.
"""
from __future__ import annotations

import gettext
from collections.abc import Callable
from functools import cache
from importlib import resources

DOMAIN = "accelcal-operator"
LANGUAGES = ("en", "de")

Translate = Callable[[str], str]


def N_(text: str) -> str:
    """Marks a msgid translated later (a table of texts); returns it unchanged."""
    return text


@cache
def translations(language: str) -> gettext.NullTranslations:
    """The catalog of ``language`` (English: the msgids themselves)."""
    if language == "en":
        return gettext.NullTranslations()
    if language not in LANGUAGES:
        raise ValueError(f"language {language!r}; allowed: {', '.join(LANGUAGES)}")
    localedir = str(resources.files(__package__) / "locale")
    return gettext.translation(DOMAIN, localedir=localedir, languages=[language])


def translator(language: str) -> Translate:
    return translations(language).gettext


# the operator's words for each reason code (the reason's own text, with its figures, follows them)
REASON_TITLES: dict[str, str] = {
    "residual_rms_mg": N_("the fit does not match the poses well enough"),
    "residual_max_mg": N_("one pose does not match the fit"),
    "gain_error_max": N_("sensitivity (gain) out of limits"),
    "cross_axis_max": N_("axes not square enough (cross-axis)"),
    "offset_max_mg": N_("zero-g offset too large"),
    "verify_error_max_mg": N_("the check after calibration is off"),
    "fit": N_("too few good poses to calibrate"),
    "nvm": N_("writing the calibration to the board failed"),
    "device": N_("the board stopped answering"),
    "port_lost": N_("the connection to the board was lost"),
    "aborted": N_("aborted by the operator"),
    "distinct_poses": N_("too few different poses"),
    "pose": N_("a pose could not be captured"),
    "temperature": N_("temperature out of range"),
    "chamber": N_("the temperature chamber failed"),
    "store": N_("the result could not be recorded"),
    "within_uncertainty_of_limit": N_("too close to a limit for the measurement's uncertainty"),
}


def language_of(station: object | None) -> str:
    """``station.language`` of a config's station section (English when there is none)."""
    return str(getattr(station, "language", "en") or "en")


def reason_title(code: str, tr: Translate) -> str:
    """The operator's words for a reason code (the code itself when there are none)."""
    title = REASON_TITLES.get(code)
    return code if title is None else tr(title)
