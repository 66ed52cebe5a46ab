"""Chamber tests offline: synthetic chamber bags, replay of the nodes' rules over a bag, the per-plateau summary of
a replay or of residual logs (with the refit model beside it), fleet (many units on Dask).

May import everything below it (physics ... recording, refit, sim, config, plots); never runs, nodes or cli.
"""
