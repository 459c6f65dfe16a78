#!/bin/sh
# Test launcher for tests that open windows: runs "$@" on a fresh virtual X server
# (xvfb-run -a, one 1024x768x24 screen) and tells it so (SOPE_XVFB=1). The first server
# number tried depends on the process id, so tests launched in parallel do not race for
# the same one. Without xvfb-run the command runs as is; the tests then use $DISPLAY or
# skip.
if command -v xvfb-run >/dev/null 2>&1; then
  SOPE_XVFB=1 exec xvfb-run -a -n $((200 + $$ % 2000)) \
    -s "-screen 0 1024x768x24 -nolisten tcp -noreset" "$@"
fi
exec "$@"
