"""The fuzz suites' shared settings (test_fuzz.py, test_fuzz_video.py): hypothesis profiles, a
small deterministic one for CI and a long one run by hand (MANTIS_FUZZ_PROFILE=long), and the
check that a property saw both of its outcomes."""
from collections import Counter
import os

from hypothesis import HealthCheck, settings

settings.register_profile('ci', max_examples=60, derandomize=True, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile('long', max_examples=3000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
PROFILE = os.environ.get('MANTIS_FUZZ_PROFILE', 'ci')


def fuzz(test):
    return settings.get_profile(PROFILE)(test)


def both_outcomes(outcomes: Counter, accepted: str) -> None:
    """Each property is checked over its examples as a whole: some inputs must get through
    (read, loaded or analysed) and some must be refused, or the property proves nothing about
    one of the two paths (every input refused would pass "analysed plausibly or refused")."""
    if PROFILE == 'long':
        print(f'\n{dict(outcomes)}')
    assert outcomes[accepted] > 0, f'no input was {accepted}: {dict(outcomes)}'
    assert outcomes['refused'] > 0, f'no input was refused: {dict(outcomes)}'
