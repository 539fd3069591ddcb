"""Detection methods as plug-ins: ``base.Method`` is what the run machinery asks of one, ``registry.METHODS``
names each (fuzzy and bayes score the four terrain maps: ``maps.py``; px4slp is PX4's grid planner:
``px4slp.py``). Adding a method is one file here plus one line in ``registry.METHODS``."""
