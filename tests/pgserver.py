"""A throwaway PostgreSQL server for tests: initdb in a temp folder, listening only on a unix
socket there, stopped and removed at the end.

The server refuses to run as root, so as root it runs as the ``postgres`` user (runuser).
Where PostgreSQL (initdb, pg_ctl) or psycopg is missing the tests that need it are skipped
with the reason, unless ACCELCAL_REQUIRE_POSTGRES=1 (set by .ci/run), which makes that a
failure: CI proves they ran.
"""
from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import tempfile
import uuid

import pytest

REQUIRE_ENV = "ACCELCAL_REQUIRE_POSTGRES"


def unavailable(reason: str):
    if os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"PostgreSQL tests required ({REQUIRE_ENV}=1) but {reason}")
    pytest.skip(reason)


def _tool(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    cands = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return cands[-1] if cands else None


class PgServer:
    def __init__(self):
        try:
            import psycopg  # noqa: F401
        except ImportError:
            unavailable("psycopg is not installed (pip install 'accelcal-station[postgresql]')")
        self.initdb, self.pg_ctl = _tool("initdb"), _tool("pg_ctl")
        if not (self.initdb and self.pg_ctl):
            unavailable("PostgreSQL server binaries (initdb, pg_ctl) not found; apt-get install postgresql")
        self.user_prefix: list[str] = []
        self.halted = False
        self.root = tempfile.mkdtemp(prefix="accelcal-pg-")
        if os.geteuid() == 0:
            try:
                pw = pwd.getpwnam("postgres")
            except KeyError:
                unavailable("running as root and there is no 'postgres' user to run the server as")
            os.chown(self.root, pw.pw_uid, pw.pw_gid)
            self.user_prefix = ["runuser", "-u", "postgres", "--"]
        os.chmod(self.root, 0o755)
        self.data, self.sock = os.path.join(self.root, "data"), self.root
        self._run([self.initdb, "-D", self.data, "-U", "accelcal", "--auth=trust", "-E", "UTF8"])
        self._run([self.pg_ctl, "-D", self.data, "-w", "-t", "30", "-l", os.path.join(self.root, "log"),
                   "-o", f"-k {self.sock} -c listen_addresses='' -p 5432 -c fsync=off", "start"])

    def _run(self, cmd: list[str]) -> None:
        r = subprocess.run(self.user_prefix + cmd, capture_output=True, text=True, timeout=60)
        if r.returncode != 0:
            shutil.rmtree(self.root, ignore_errors=True)
            unavailable(f"{os.path.basename(cmd[0])} failed: {(r.stderr or r.stdout).strip()[-300:]}")

    def url(self, db: str = "postgres") -> str:
        return f"postgresql://accelcal@/{db}?host={self.sock}&port=5432"

    def new_database(self) -> str:
        import psycopg
        name = "t_" + uuid.uuid4().hex[:12]
        with psycopg.connect(host=self.sock, port=5432, user="accelcal", dbname="postgres", autocommit=True) as c:
            c.execute(f"CREATE DATABASE {name}")
        return self.url(name)

    def halt(self) -> None:
        """Stop the server at once (``pg_ctl stop -m immediate``: as a crash or a pulled cable
        looks to the clients); ``resume`` starts it again on the same data."""
        self._run([self.pg_ctl, "-D", self.data, "-m", "immediate", "-w", "stop"])
        self.halted = True

    def resume(self) -> None:
        self._run([self.pg_ctl, "-D", self.data, "-w", "-t", "30", "-l", os.path.join(self.root, "log"),
                   "-o", f"-k {self.sock} -c listen_addresses='' -p 5432 -c fsync=off", "start"])
        self.halted = False

    def stop(self) -> None:
        subprocess.run(self.user_prefix + [self.pg_ctl, "-D", self.data, "-m", "immediate", "stop"],
                       capture_output=True, timeout=60)
        shutil.rmtree(self.root, ignore_errors=True)
