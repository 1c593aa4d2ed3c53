"""`mantis identify --spread`'s part: the spread fitted to the strikes (spread_fit), written
into each group's scene file, its report and the report's text."""
from __future__ import annotations

from collections.abc import Callable
import math
from pathlib import Path

import yaml

from mantis_sim.studies.shared.finite_values import json_safe

from . import spread_fit
from .strike_inputs import StrikeInputs


def fit_and_write_spreads(inputs: StrikeInputs, latent: str, out: Path, mapper, strikes,
                          scenes: dict, files: dict,
                          log: Callable[[str], None] = lambda _: None) -> dict:
    """Fit the spread (spread_fit, ``latent`` 'KEY=LO:HI'), then write each group's scene file,
    ``files`` group -> (the scene file, where to write it with its spread; in ``out``); the
    report's 'spread' entry. Nothing is written if the fit fails."""
    spreads, latents, model = spread_fit.fit_spreads(
        scenes, strikes, mapper, latent, sources=inputs.sources(), log=log)
    out.mkdir(parents=True, exist_ok=True)
    for group, (source, target) in files.items():
        doc = yaml.safe_load(source.read_text(encoding='utf-8'))
        doc['spread'] = json_safe(spreads[group].to_mapping())
        target.write_text(yaml.safe_dump(doc, sort_keys=False, width=100), encoding='utf-8')
    return {'latent': model.key,
            'means': {g: {'value': m, 'std_error': se} for g, (m, se) in model.means.items()},
            'day_sd': {'value': model.day_sd, 'std_error': model.day_sd_std_error},
            'strike_sd': {'value': model.strike_sd, 'std_error': model.strike_sd_std_error},
            'days': model.days, 'strikes': model.strikes,
            'discrepancy': {d.metric: {'bias': d.bias, 'bias_std_error': d.bias_std_error,
                                       'sd': d.sd}
                            for d in next(iter(spreads.values())).discrepancy},
            'strike_latents': {x.strike.trial: x.value for x in latents}}


def _std_error_text(value: float) -> str:
    return f'{value:.2f}' if math.isfinite(value) else 'at zero: the days agree'


def spread_text(spread: dict) -> str:
    lines = [f'spread: {spread["latent"]} over {spread["strikes"]} strikes of '
             f'{spread["days"]} recording days (mixed model, REML)',
             '  group        mean (s.e.)']
    lines += [f'  {g:12s} {m["value"]:+6.2f} ({m["std_error"]:.2f})'
              for g, m in spread['means'].items()]
    lines.append(f'  between days: sd {spread["day_sd"]["value"]:.2f} '
                 f'({_std_error_text(spread["day_sd"]["std_error"])}); within a day: sd '
                 f'{spread["strike_sd"]["value"]:.2f} '
                 f'({_std_error_text(spread["strike_sd"]["std_error"])})')
    lines.append('  discrepancy, measured/simulated - 1, every group: bias (s.e.), scatter (sd)')
    for metric, d in spread['discrepancy'].items():
        lines.append(f'  {metric:20s} {100 * d["bias"]:+5.1f} % ({100 * d["bias_std_error"]:.1f} '
                     f'%)  {100 * d["sd"]:.1f} %')
    return '\n'.join(lines)
