"""The paper's single-target segmentation (Arif et al.): its energies, the exact graph cut
and the fast solver, one target or several; the multi-object tracker does not use it."""
