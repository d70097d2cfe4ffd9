# CHOLMOD (SuiteSparse) has no CMake package on Debian 12: find the header and libraries and wrap
# them in one imported target. Its BLAS is whatever libblas.so.3 points to (OpenBLAS when
# libopenblas0-pthread is installed, see scripts/install-deps.sh).
if(TARGET meshdeform::cholmod)
  return()
endif()
find_path(CHOLMOD_INCLUDE_DIR cholmod.h PATH_SUFFIXES suitesparse REQUIRED)
find_library(CHOLMOD_LIBRARY cholmod REQUIRED)
find_library(SUITESPARSECONFIG_LIBRARY suitesparseconfig REQUIRED)
add_library(meshdeform::cholmod INTERFACE IMPORTED)
target_include_directories(meshdeform::cholmod INTERFACE ${CHOLMOD_INCLUDE_DIR})
target_link_libraries(meshdeform::cholmod INTERFACE ${CHOLMOD_LIBRARY} ${SUITESPARSECONFIG_LIBRARY})
