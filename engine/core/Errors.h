/// @file Errors.h
/// @brief Error types that carry what a user needs to fix their input.
#pragma once

#include <stdexcept>
#include <string>

namespace voxlat {

/// Bad user input: a message naming the file, line and fix. The command line prints what() and
/// exits non-zero; no output file is left behind.
class InputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// A job the machine cannot hold (memory) or a field that produced non-finite values.
class JobError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// The caller cancelled the job (JobContext::cancel, Ctrl-C): nothing was written.
class Cancelled : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

}  // namespace voxlat
