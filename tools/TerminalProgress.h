/// @file TerminalProgress.h
/// @brief The command line's side of a job context: progress bars and warnings on stderr.
#pragma once

#include "engine/core/JobContext.h"

namespace voxlat::cli {

/// Wires @a context to the terminal: a bar per stage when stderr is a terminal and @a quiet is
/// off, and every warning printed as "warning: ..." (also when quiet).
void attachTerminal(JobContext& context, bool quiet);

/// Makes SIGINT and SIGTERM cancel @a context (the job then unwinds and removes its temporary
/// files); returns the signal received so far, 0 if none.
void cancelOnSignals(JobContext& context);
int receivedSignal();

}  // namespace voxlat::cli
