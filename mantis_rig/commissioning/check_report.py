"""What `mantis doctor` asks for and what it finds: the run's Options, and a Report of Checks,
each OK / WARN / FAIL with what it found and, unless OK, the fix in one line."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

OK, WARN, FAIL = 'OK', 'WARN', 'FAIL'
JOG_M = 1.0e-3
JOG_SPEED_M_PER_S = 0.5e-3
REST_S = 1.0


@dataclass
class Check:
    name: str
    status: str
    found: str
    fix: str = ''

    def line(self) -> str:
        text = f'{self.name}: {self.found}'
        if self.fix and self.status != OK:
            text += f' -- fix: {self.fix}'
        return f'{self.status:<4}  ' + ' '.join(text.split())


@dataclass
class Options:
    backend: str = 'hardware'
    params: object = None               # rig_params.RigParams
    move: bool = False
    jog_m: float = JOG_M
    jog_speed_m_per_s: float = JOG_SPEED_M_PER_S
    rest_s: float = REST_S
    real_time_factor: float = 1.0       # sim backend
    home_timeout_s: float = 60.0


class Report:
    def __init__(self):
        self.checks: list[Check] = []
        self.moved = False
        self.stage_status: Optional[str] = None     # the KDC101's status_mode, once open

    def add(self, name, status, found, fix='') -> Check:
        check = Check(name, status, found, fix)
        self.checks.append(check)
        return check

    @property
    def failed(self) -> bool:
        return any(c.status == FAIL for c in self.checks)

    def counts(self) -> dict:
        return {s: sum(c.status == s for c in self.checks) for s in (OK, WARN, FAIL)}


def one_line(exc: BaseException) -> str:
    """An exception's message on one line, as a check's finding."""
    return ' '.join(str(exc).split())


__all__ = ['Check', 'FAIL', 'JOG_M', 'JOG_SPEED_M_PER_S', 'OK', 'Options', 'REST_S', 'Report',
           'WARN', 'one_line']
