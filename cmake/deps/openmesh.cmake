# OpenMesh: Debian ships OpenMeshConfig.cmake with targets OpenMeshCore/OpenMeshTools; other
# package managers name them differently, so callers link meshdeform::openmesh only.
if(TARGET meshdeform::openmesh)
  return()
endif()
find_package(OpenMesh CONFIG REQUIRED)
add_library(meshdeform::openmesh INTERFACE IMPORTED)
target_link_libraries(meshdeform::openmesh INTERFACE OpenMeshCore)
target_compile_definitions(meshdeform::openmesh INTERFACE _USE_MATH_DEFINES)
