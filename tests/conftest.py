"""The suite's one process-wide setting: a suite started in the background without job
control (`pytest &` in a script) has SIGINT ignored, and the children the Ctrl-C tests start
would inherit that and never stop. SIGINT is given Python's usual handler, which a child's
exec resets to the default."""

import signal

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
