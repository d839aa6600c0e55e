/// @file error.h
/// @brief Typed exceptions for bad input. Library code throws; only main() turns them
///        into an exit code and one line on stderr.
#pragma once

#include <stdexcept>
#include <string>

namespace flyover {

/// The input data (a file, a grid, a mask) is unusable; the message names it and says why.
struct InputError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// A parameter has an invalid value or an unknown name; the message names it.
struct ParameterError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

} // namespace flyover
