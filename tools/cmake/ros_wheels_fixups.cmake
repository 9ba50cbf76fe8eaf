# Build-time fix-ups for building ROS 2 interface packages against the ros-jazzy-* PyPI wheels.
#
# Injected from the command line, never included by a package's CMakeLists.txt:
#   cmake -DCMAKE_PROJECT_INCLUDE=<repo>/tools/cmake/ros_wheels_fixups.cmake ...
# CMake includes this file right after the package's project() call. It defers one call to the
# end of the top-level directory, i.e. after every find_package() and rosidl_generate_interfaces(),
# but before CMake's generate step checks the include directories of imported targets.
#
# The problem it fixes: the wheels' exported CMake targets (e.g. the *__rosidl_generator_py
# targets of builtin_interfaces, std_msgs, geometry_msgs) carry include directories of the machine
# the wheels were built on (/opt/python/cp311-cp311/include/python3.11), and the generate step
# fails with "Imported target ... includes non-existent path". Those entries are dropped here;
# the package's own targets still get this interpreter's headers from its find_package(Python3).
# On a full ROS install nothing is missing, so this file changes nothing there.
include_guard(GLOBAL)
if(CMAKE_VERSION VERSION_LESS 3.19)
  message(FATAL_ERROR "ros_wheels_fixups.cmake needs CMake 3.19 or newer (cmake_language(DEFER))")
endif()

# Imported targets of DIR and of its subdirectories, recursively, into OUT_VAR.
function(_ros_wheels_imported_targets dir out_var)
  get_property(_targets DIRECTORY "${dir}" PROPERTY IMPORTED_TARGETS)
  get_property(_subdirs DIRECTORY "${dir}" PROPERTY SUBDIRECTORIES)
  foreach(_subdir IN LISTS _subdirs)
    _ros_wheels_imported_targets("${_subdir}" _sub_targets)
    list(APPEND _targets ${_sub_targets})
  endforeach()
  set(${out_var} "${_targets}" PARENT_SCOPE)
endfunction()

function(_ros_wheels_drop_missing_include_dirs)
  _ros_wheels_imported_targets("${CMAKE_SOURCE_DIR}" _targets)
  set(_dropped "")
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs "${_target}" INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_kept "")
    set(_changed FALSE)
    foreach(_dir IN LISTS _dirs)
      # Only plain absolute paths are checked; generator expressions are kept as they are.
      if(IS_ABSOLUTE "${_dir}" AND NOT _dir MATCHES "\\$<" AND NOT EXISTS "${_dir}")
        set(_changed TRUE)
        list(APPEND _dropped "${_dir}")
      else()
        list(APPEND _kept "${_dir}")
      endif()
    endforeach()
    if(_changed)
      set_target_properties("${_target}" PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
    endif()
  endforeach()
  if(_dropped)
    list(REMOVE_DUPLICATES _dropped)
    message(STATUS "ros_wheels_fixups: dropped non-existent include dirs from imported targets: ${_dropped}")
  endif()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _ros_wheels_drop_missing_include_dirs)
