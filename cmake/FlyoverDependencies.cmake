# Finds every third-party library flyover uses (all from Debian 12's archive; see
# scripts/setup.sh). Pitfalls are from ../shared/docs/toolchain.md.

# oneTBB's config first: OpenVDB's Find module would otherwise define a partial TBB::tbb.
find_package(TBB 2021 CONFIG REQUIRED COMPONENTS tbb)

# OpenVDB: Debian ships only a Find module, and it forces BUILD_SHARED_LIBS=ON in our scope.
list(APPEND CMAKE_MODULE_PATH "/usr/lib/${CMAKE_LIBRARY_ARCHITECTURE}/cmake/OpenVDB")
set(_flyover_saved_shared "${BUILD_SHARED_LIBS}")
find_package(OpenVDB REQUIRED)
set(BUILD_SHARED_LIBS "${_flyover_saved_shared}" CACHE BOOL "" FORCE)
set(BUILD_SHARED_LIBS "${_flyover_saved_shared}")

find_package(OpenMesh CONFIG REQUIRED)
find_package(embree 3 CONFIG REQUIRED)
find_package(ITK 5.2 REQUIRED COMPONENTS
  ITKCommon ITKIOImageBase ITKIONIFTI ITKIONRRD ITKIOMeta ITKIOGDCM ITKImageIntensity)
find_package(CLI11 CONFIG REQUIRED)
find_package(nlohmann_json 3 CONFIG REQUIRED)
find_package(PNG REQUIRED)
find_package(Threads REQUIRED)

# ISA-L (libisal-dev): gzip inflation of .nii.gz voxels (volume/io/gzip_stream.h), streamed at
# about 1.9x zlib's speed, and the PNGs' deflate (pipeline/artifact_io.cpp encodePng), ~4x
# zlib's run-length deflate. Its pkg-config file, as Debian ships it.
find_package(PkgConfig REQUIRED)
pkg_check_modules(ISAL REQUIRED IMPORTED_TARGET GLOBAL libisal)

find_path(XXHASH_INCLUDE_DIR xxhash.h REQUIRED)
find_library(XXHASH_LIBRARY xxhash REQUIRED)
add_library(flyover_xxhash INTERFACE)
target_include_directories(flyover_xxhash SYSTEM INTERFACE "${XXHASH_INCLUDE_DIR}")
target_link_libraries(flyover_xxhash INTERFACE "${XXHASH_LIBRARY}")

# ITK without ITK_USE_FILE: include dirs as SYSTEM, IO factories registered explicitly
# in volume/image_io.cpp, so ITK's global definitions stay out of the other modules.
add_library(flyover_itk INTERFACE)
target_include_directories(flyover_itk SYSTEM INTERFACE ${ITK_INCLUDE_DIRS})
target_link_libraries(flyover_itk INTERFACE ${ITK_LIBRARIES})
# NIfTI-2: only nifticlib's header struct (libnifti2-dev), no library; see volume/image_io.cpp.
find_path(NIFTI2_INCLUDE_DIR nifti/nifti2.h REQUIRED)
target_include_directories(flyover_itk SYSTEM INTERFACE "${NIFTI2_INCLUDE_DIR}")

# OpenMesh's config exports include dirs as non-system; wrap them as SYSTEM.
add_library(flyover_openmesh INTERFACE)
get_target_property(_om_inc OpenMeshCore INTERFACE_INCLUDE_DIRECTORIES)
if(_om_inc)
  target_include_directories(flyover_openmesh SYSTEM INTERFACE ${_om_inc})
endif()
target_link_libraries(flyover_openmesh INTERFACE OpenMeshCore OpenMeshTools)
target_compile_definitions(flyover_openmesh INTERFACE _USE_MATH_DEFINES)
