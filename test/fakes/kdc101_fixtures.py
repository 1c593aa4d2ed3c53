"""Fixtures shared by the tests of the stage's driver and of `mantis doctor` (a plugin of
test/conftest.py)."""
import pytest

from fakes.kdc101_emulator import Kdc101Emulator, fds_open_on


@pytest.fixture
def make_emulator():
    emulators = []

    def make(**kwargs):
        emulators.append(Kdc101Emulator(**kwargs).start())
        return emulators[-1]

    yield make
    for emulator in emulators:
        # only the emulator's own slave fd may remain: every stage closed its port
        assert len(fds_open_on(emulator.port)) == 1, 'a serial port was left open'
        emulator.close()
        assert not emulator.thread_alive
