# The cmeel-urdfdom wheel ships urdfdom's CMake config but not urdfdom_headers' one, which
# pinocchioConfig.cmake asks for; the headers themselves are in the same cmeel prefix.
find_path(urdfdom_headers_INCLUDE_DIRS urdf_model/model.h PATH_SUFFIXES include include/urdfdom_headers)
set(urdfdom_headers_FOUND TRUE)
set(urdfdom_headers_VERSION 1.0.0)
if(NOT TARGET urdfdom_headers::urdfdom_headers)
  add_library(urdfdom_headers::urdfdom_headers INTERFACE IMPORTED)
  if(urdfdom_headers_INCLUDE_DIRS)
    set_target_properties(urdfdom_headers::urdfdom_headers PROPERTIES
                          INTERFACE_INCLUDE_DIRECTORIES "${urdfdom_headers_INCLUDE_DIRS}")
  endif()
endif()
