# Included by each package's CMakeLists.txt here, after its find_package calls.
# The registry's wheels were built on another machine: their exported targets name that
# machine's Python and NumPy include directories. Point them at this machine's (given by
# scripts/dev as TOCONTROL_PYTHON_INCLUDE and TOCONTROL_NUMPY_INCLUDE).
if(TOCONTROL_PYTHON_INCLUDE AND TOCONTROL_NUMPY_INCLUDE)
  get_property(_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _imported)
    get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_mapped "")
    foreach(_dir IN LISTS _dirs)
      if(NOT EXISTS "${_dir}" AND _dir MATCHES "/include/python3\\.[0-9]+$")
        set(_dir "${TOCONTROL_PYTHON_INCLUDE}")
      elseif(NOT EXISTS "${_dir}" AND _dir MATCHES "/numpy/(_core|core)/include$")
        set(_dir "${TOCONTROL_NUMPY_INCLUDE}")
      endif()
      list(APPEND _mapped "${_dir}")
    endforeach()
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_mapped}")
  endforeach()
endif()
