"""
YAML text read into Python, or one line saying what is wrong and where.

Every YAML a user hands the package goes through :func:`parse_yaml`: scene files and the pump's
legs, a bag's metadata.yaml, the player's QoS overrides, a report's reference file. PyYAML's
failures are more than its YAMLError: nesting deeper than Python's recursion limit raises
RecursionError, an integer of thousands of digits or a date like 2026-13-45 a ValueError.
"""

import sys
from typing import Any

import yaml

from softseq_ros.errors import UserError


def parse_yaml(text: str, shown: str, error: type[UserError] = UserError,
               loader: type = yaml.SafeLoader) -> Any:
    """``text`` parsed with ``loader``, or ``error`` naming ``shown`` (a file or a setting)."""
    try:
        return yaml.load(text, Loader=loader)  # noqa: S506 - safe loaders only
    except RecursionError:
        # PyYAML nests one Python call per level: thousands of '[' exhaust the stack.
        raise error(f"{shown}: YAML nested too deeply (more levels than Python's recursion "
                    f'limit of {sys.getrecursionlimit()})') from None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f'line {mark.line + 1}, column {mark.column + 1}' if mark else 'YAML'
        problem = err.problem or err.context or 'invalid YAML'
        raise error(f'{shown}: {where}: {problem}') from None
    except yaml.YAMLError as err:
        raise error(f'{shown}: YAML: {" ".join(str(err).split())}') from None
    except ValueError as err:
        # PyYAML's own constructors: their messages carry no position.
        problem = ' '.join(str(err).split(';')[0].split())
        raise error(f'{shown}: YAML: a value cannot be read ({problem})') from None
