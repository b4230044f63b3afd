"""`tofcut bench`: every benchmark, one stage a module, with its timing, report and plot."""
