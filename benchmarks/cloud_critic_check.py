"""Does a trained cloud critic know that its actor could do better?

``benchmarks/critic_check.py --kind cloud`` under the name the committed results cite: the
same options without ``--kind``, the same output file (``cloud_critic_check_<model>.md``).

Usage (about 10 s on an idle 2-core machine):
    python benchmarks/cloud_critic_check.py --model released --out benchmarks/results
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import critic_check

from mivecc_env import cli_args


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    return critic_check.main(argv, fixed_kind="cloud", prog="benchmarks/cloud_critic_check.py")


if __name__ == "__main__":
    sys.exit(cli_args.run(main))
