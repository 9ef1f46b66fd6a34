"""Argument helpers shared by the subcommands that build a plant (simulate, card-sim)."""

import argparse
from collections.abc import Iterable
import sys
from typing import TextIO

from motor_id.effects import MECHANISMS, parse_effect_args
from motor_id.errors import ConfigError
from motor_id.model import Plant
from motor_id.recording import Recording


def plant_from_args(params_path: str | None, effect_items: Iterable[str] | None) -> Plant:
    """The plant of ``--params FILE`` (default: the paper's motor) plus ``--effect`` items."""
    plant = Plant.from_json(params_path) if params_path else Plant()
    if effect_items:
        plant = Plant(plant.params, plant.input_kind,
                      {**plant.effects, **parse_effect_args(effect_items)})
    return plant


def parse_noise(text: str, what: str) -> list[float]:
    """``SPEED[,CURRENT]`` -> list of floats; ``what`` names the unit in the message."""
    try:
        return [float(x) for x in text.split(',')]
    except ValueError:
        raise ConfigError(f'--noise takes SPEED[,CURRENT] {what}, got {text!r}') from None


def add_mechanism_argument(parser: argparse.ArgumentParser) -> None:
    """``--mechanism``: what the joint moves (its gravity in the model)."""
    parser.add_argument('--mechanism', choices=MECHANISMS, default=None,
                        help='what the joint moves: a shaft or wheel (simple), an '
                             'elevator (constant gravity kG) or an arm (kG cos(theta + '
                             'offset) from the measured position): the gravity is in the '
                             "model from the start (default: the SysId log's test, Arm or "
                             'Elevator, else simple)')


def mechanism_for(args: argparse.Namespace, rec: Recording,
                  stream: TextIO | None = None) -> str:
    """The mechanism ``--mechanism`` names, else the recording's (a SysId JSON log's
    ``"test": "Arm"`` or ``"Elevator"``, said on ``stream``), else ``simple``."""
    given = getattr(args, 'mechanism', None)
    if given:
        return str(given)
    logged = rec.meta.get('mechanism')
    if logged in MECHANISMS:
        print(f"mechanism: {logged} (the log's test; --mechanism to choose another)",
              file=stream or sys.stderr)
        return str(logged)
    return MECHANISMS[0]
