"""`motor-id validate`: score a saved model on another recording (simulation from input)."""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from motor_id.cli.common import add_mechanism_argument, mechanism_for
from motor_id.cli.data_args import add_data_arguments, DATA_HELP, load_runs
from motor_id.errors import ConfigError
from motor_id.identify.validation import SavedModel, validate, Validation


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id validate`."""
    parser.add_argument('model', metavar='MODEL',
                        help='the JSON of `motor-id fit --json` or `motor-id analyze --json`')
    parser.add_argument('data', metavar='DATA', nargs='+',
                        help=DATA_HELP + '; several: separate runs, each simulated anew')
    parser.add_argument('--init-samples', type=int, default=None, metavar='N',
                        help='samples at the start of each run that set its unmeasured '
                             'initial state (left out of the score; default: as few as '
                             'needed, 1, or 2 without a measured current)')
    parser.add_argument('--json', metavar='OUT', help='write the scores as JSON')
    parser.add_argument('--csv', metavar='OUT',
                        help='write time,segment,<channel>_measured,<channel>_simulated')
    parser.add_argument('--plot', metavar='OUT.png', help='plot measured vs simulated')
    add_mechanism_argument(parser)
    add_data_arguments(parser)


def load_model(path: str) -> SavedModel:
    """A :class:`SavedModel` from a report file; one-line errors for a bad file."""
    try:
        with open(path) as fh:
            report = json.load(fh)
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read the model ({exc.strerror})') from exc
    except json.JSONDecodeError as exc:
        raise ConfigError(f'{path}: not JSON ({exc.msg} at line {exc.lineno})') from exc
    return SavedModel.from_report(report, source=str(path))


def run(args: argparse.Namespace) -> int:
    """Simulate the model on the recording(s), print and write the scores."""
    model = load_model(args.model)
    rec = load_runs(args)
    val = validate(model, rec, args.init_samples, mechanism_for(args, rec))
    print(val.summary())
    if args.json:
        from motor_id.output import write_json
        out = val.to_dict()
        out['data'] = {'source': rec.meta.get('source'), 'samples': len(rec)}
        write_json(out, args.json)
        print(f'wrote {args.json}')
    if args.csv:
        header, rows = val.rows()
        try:
            np.savetxt(args.csv, rows, delimiter=',', header=','.join(header), comments='',
                       fmt='%.10g')
        except OSError as exc:
            raise ConfigError(f'{args.csv}: cannot write ({exc.strerror})') from exc
        print(f'wrote {args.csv}')
    if args.plot:
        _plot(val, args.plot, os.path.basename(str(args.model)))
        print(f'wrote {args.plot}')
    return 0


def _plot(val: Validation, path: str, title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    chans = list(val.channels)
    fig, axes = plt.subplots(len(chans), 1, figsize=(10, 3 * len(chans)), sharex=True,
                             squeeze=False)
    for ax, ch in zip(axes[:, 0], chans, strict=True):
        ax.plot(val.time, val.measured[ch], lw=0.8, label='measured')
        ax.plot(val.time, val.simulated[ch], lw=0.8, label='simulated (input only)')
        m = val.channels[ch]
        ax.set_ylabel(ch)
        ax.set_title(f'{ch}: fit {m["fit_percent"]:.1f} %, RMSE {m["rmse"]:.3g}',
                     fontsize=9)
        ax.legend(loc='upper right', fontsize=8)
    axes[-1, 0].set_xlabel('time [s]')
    fig.suptitle(f'motor-id validate: {title}')
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise ConfigError(f'{path}: cannot write ({exc.strerror})') from exc
    finally:
        plt.close(fig)
