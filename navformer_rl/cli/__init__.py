"""The ``navformer`` command line: the dispatcher (:mod:`~navformer_rl.cli.main`). Each subcommand's parser
lives beside the library function it runs, with the argument types of :mod:`navformer_rl.utils.cli_args`; no
library module imports this package."""

from navformer_rl.cli.main import SUBCOMMAND_MODULES, USER_ERRORS, build_parser, main

__all__ = ["SUBCOMMAND_MODULES", "USER_ERRORS", "build_parser", "main"]
