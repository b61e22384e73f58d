"""The self-test step of a board's run (issue 40; docs/self-test.md): the chip's built-in self-test
once, before the poses, on a still board, judged on the data sheet's limits or the config's."""
from __future__ import annotations

from collections.abc import Callable

from ..acceptance.reasons import Reason
from ..drivers.base import Driver
from ..drivers.self_test import with_limits
from .capture import wait_still
from .report import RunReport
from .settings import StationConfig
from .verdict import Stage


def self_test_step(driver: Driver, cfg: StationConfig, rep: RunReport, echo: Callable[[str], None]
                   ) -> tuple[bool, int]:
    """Run and judge the self-test; a failure is recorded FAIL ``self_test`` (no poses follow, nothing is
    burned).  (True when the poses may follow: passed, no self-test on this driver, or turned off by
    ``acceptance.self_test``; the samples read while waiting for a still board)."""
    lim = cfg.limits.self_test
    if not (lim.run and driver.supports_self_test):
        return True, 0
    if driver.self_test_skipped:  # a part the config accepted whose self-test is not the data sheet's
        echo(driver.self_test_skipped)
        rep.events.append(driver.self_test_skipped)
        return True, 0
    echo("self-test")
    # on a still board: a move between the two averages would read as self-test response
    read = wait_still(driver, cfg.capture)
    res = driver.self_test(cfg.capture.self_test_samples)
    if lim.overridden:
        res = with_limits(res, lim.low_g, lim.high_g, lim.tolerance, "the config's acceptance section")
    rep.self_test = res.to_json()
    for a in res.axes:
        echo(f"  {a.axis}: change {a.change_g * 1e3:+.1f} mg, {a.unit} {a.value:.4g} in "
             f"[{a.low:.4g}, {a.high:.4g}] {'ok' if a.ok else 'FAIL'}")
    failed = res.reason()
    if failed is not None:
        rep.record(Stage.SELF_TEST, Reason("self_test", failed))
        echo(f"FAIL: {failed} (no poses, nothing burned)")
        return False, read
    rep.record(Stage.SELF_TEST)
    return True, read
