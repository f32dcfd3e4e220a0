"""Small utilities with no paper meaning: argument checks (``checks``), the subcommands' argument types
(``cli_args``), devices, atomic files and folder locks (``durable``), the allocator setting, mp4 writing,
Ctrl-C handling of process pools (``interrupts``)."""
