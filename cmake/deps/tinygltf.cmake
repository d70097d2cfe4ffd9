# tinygltf: Debian builds it as a shared library with TinyGLTF::TinyGLTF; elsewhere it is
# header-only. Callers link meshdeform::tinygltf only.
if(TARGET meshdeform::tinygltf)
  return()
endif()
find_package(TinyGLTF CONFIG REQUIRED)
add_library(meshdeform::tinygltf INTERFACE IMPORTED)
target_link_libraries(meshdeform::tinygltf INTERFACE TinyGLTF::TinyGLTF)
