"""Performance and accuracy-vs-time studies. Run all: ``python -m benchmarks`` (or ``make bench-perf``);
one: ``python -m benchmarks spectro``. Each prints a table of figures measured in one run."""
