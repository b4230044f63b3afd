"""One module per `tofcut` command (named as the command; `register` adds its parser), and
the argument helpers they share; no command imports another."""
