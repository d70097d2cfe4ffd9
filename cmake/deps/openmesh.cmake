# OpenMesh: Debian's libopenmesh-dev exports the imported targets OpenMeshCore / OpenMeshTools;
# other package managers name them OpenMesh::OpenMeshCore or ship no config at all. Callers link
# meshdeform::openmesh only (PRIVATE: core's public headers stay Eigen-only).
if(TARGET meshdeform::openmesh)
  return()
endif()
find_package(OpenMesh CONFIG QUIET)
add_library(meshdeform::openmesh INTERFACE IMPORTED)
if(TARGET OpenMeshTools)
  target_link_libraries(meshdeform::openmesh INTERFACE OpenMeshTools OpenMeshCore)
elseif(TARGET OpenMesh::OpenMeshTools)
  target_link_libraries(meshdeform::openmesh INTERFACE OpenMesh::OpenMeshTools OpenMesh::OpenMeshCore)
else()
  find_path(OPENMESH_INCLUDE_DIR OpenMesh/Core/Mesh/TriMeshT.hh REQUIRED)
  find_library(OPENMESH_CORE_LIBRARY OpenMeshCore REQUIRED)
  find_library(OPENMESH_TOOLS_LIBRARY OpenMeshTools REQUIRED)
  target_include_directories(meshdeform::openmesh INTERFACE ${OPENMESH_INCLUDE_DIR})
  target_link_libraries(meshdeform::openmesh INTERFACE ${OPENMESH_TOOLS_LIBRARY}
                        ${OPENMESH_CORE_LIBRARY})
endif()
# OpenMesh's headers use M_PI and friends.
target_compile_definitions(meshdeform::openmesh INTERFACE _USE_MATH_DEFINES)
