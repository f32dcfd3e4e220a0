"""The ``navformer`` command line: the dispatcher (:mod:`~navformer_rl.cli.main`) and argument types
(:mod:`~navformer_rl.cli.args`). Each subcommand's parser lives beside the library function it runs."""

from navformer_rl.cli.main import SUBCOMMAND_MODULES, USER_ERRORS, build_parser, main

__all__ = ["SUBCOMMAND_MODULES", "USER_ERRORS", "build_parser", "main"]
