"""`python -m nedrt_train COMMAND ...` (also `torchrun -m nedrt_train train ...`): the `nedrt-train` command."""
import sys

from .cli import main

sys.exit(main())
