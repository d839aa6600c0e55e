// Debian's ITK 5.2 headers were generated for GCC only ("#error Unsupported compiler" under
// clang), and libFuzzer needs clang. This header is force-included (-include) before any ITK
// header: it hides __clang__ while ITK's compiler detection runs (its include guard then
// keeps it from running again), so ITK reads its GCC feature table. The fuzz target is
// compiled with -fgnuc-version=10 so that table sees a modern GCC (glibc would switch on
// GCC 11 attributes that clang lacks at 11 and above).
#pragma once
#pragma push_macro("__clang__")
#undef __clang__
#include <ITK-5.2/itk_compiler_detection.h>
#pragma pop_macro("__clang__")
