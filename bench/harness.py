"""The benchmark harness, run from a checkout: ``python bench/harness.py ARGS`` is
``clraster bench ARGS``. The code is `clraster.bench.harness` (inside the package, so that
an installed clraster has it too); results go to bench/results/ by default."""

from clraster.bench.harness import main

if __name__ == "__main__":
    raise SystemExit(main())
