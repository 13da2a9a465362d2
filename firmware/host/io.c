/* The step's inputs and outputs: one for the library, outside the per-board state. */
#include "hexbot_host.h"

hexbot_io_t hexbot_io;
hexbot_flush_fn hexbot_flush;
