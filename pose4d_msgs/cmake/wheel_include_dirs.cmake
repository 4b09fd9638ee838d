# Included by an interface package's CMakeLists.txt after its find_package() calls and before
# rosidl_generate_interfaces().
#
# ROS 2 Jazzy from PyPI wheels: the wheels' exported CMake targets carry include directories of
# the machine that built them (/opt/python/...), and CMake refuses imported targets whose include
# directories do not exist. Drop the missing ones (generator expressions are kept). On a normal
# ROS install every directory exists and this changes nothing.
get_property(_pose4d_targets DIRECTORY PROPERTY IMPORTED_TARGETS)
foreach(_target IN LISTS _pose4d_targets)
  get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
  if(_dirs)
    set(_kept "")
    foreach(_dir IN LISTS _dirs)
      if(_dir MATCHES "^\\$<" OR EXISTS "${_dir}")
        list(APPEND _kept "${_dir}")
      endif()
    endforeach()
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
  endif()
endforeach()
