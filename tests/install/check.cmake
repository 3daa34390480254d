# The installed tree as another project sees it (the ctest InstallTest):
#   cmake -DBUILD=<build dir> -DSRC=<source dir> -DWORK=<scratch dir> -DCXX=<compiler>
#         [-DPYTHON=<python the module is built for>] -P tests/install/check.cmake
# installs BUILD into WORK/prefix, configures, builds and runs tests/install/ against it
# with nothing but CMAKE_PREFIX_PATH, runs the installed command, and imports the installed
# Python package from another folder with nothing but PYTHONPATH.
function(step what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "InstallTest: ${what} failed (${rc}):\n${out}${err}")
  endif()
  string(LENGTH "${out}" n)
  if(n LESS 2000)
    message(STATUS "${what}: ${out}${err}")
  else()
    message(STATUS "${what}: done")
  endif()
  set(out "${out}" PARENT_SCOPE)
endfunction()

file(REMOVE_RECURSE ${WORK})
set(prefix ${WORK}/prefix)
step("cmake --install" ${CMAKE_COMMAND} --install ${BUILD} --prefix ${prefix})
foreach(f bin/cvt-engine bin/cvt-engine-core lib/cmake/cvt/cvtConfig.cmake include/cvt-engine/engine/ode/ode.hpp
          share/cvt-engine/configs/mini.toml share/doc/cvt-engine/LICENSE share/doc/cvt-engine/README.md)
  if(NOT EXISTS ${prefix}/${f})
    message(FATAL_ERROR "InstallTest: ${f} is not installed")
  endif()
endforeach()

step("configure the outside project" ${CMAKE_COMMAND} -S ${SRC}/tests/install -B ${WORK}/outside
     -DCMAKE_PREFIX_PATH=${prefix} -DCMAKE_CXX_COMPILER=${CXX} -DCMAKE_BUILD_TYPE=Release
     -DCVT_HIRES_SOURCE=${prefix}/share/doc/cvt-engine/examples/example_hires.cpp)
step("build it" ${CMAKE_COMMAND} --build ${WORK}/outside -j 2)
step("HIRES through cvt::ode" ${WORK}/outside/outside_hires)
step("the mini model through cvt::engine" ${WORK}/outside/outside_engine ${prefix}/share/cvt-engine/configs/mini.toml)

step("the installed command" ${prefix}/bin/cvt-engine --version)
if(NOT out MATCHES "^cvt-engine [0-9]+\\.[0-9]+\\.[0-9]+")
  message(FATAL_ERROR "InstallTest: the installed cvt-engine --version says: ${out}")
endif()
step("a run of the installed command" ${CMAKE_COMMAND} -E chdir ${WORK}
     ${prefix}/bin/cvt-engine run ${prefix}/share/cvt-engine/configs/mini.toml --t-end 0.0005 -o ${WORK}/mini.h5 -q)

if(PYTHON)
  file(GLOB pydirs LIST_DIRECTORIES true ${prefix}/lib*/python*/site-packages)
  list(LENGTH pydirs n)
  if(NOT n EQUAL 1)
    message(FATAL_ERROR "InstallTest: the Python package is not installed once under ${prefix}: ${pydirs}")
  endif()
  step("import the installed package" ${CMAKE_COMMAND} -E env --unset=PYTHONPATH PYTHONPATH=${pydirs}
       ${CMAKE_COMMAND} -E chdir ${WORK} ${PYTHON} -c
       "import cvt_engine as c, sys; print(c.__file__, c.__version__, c.shipped_config('mini')); sys.exit(not (c.__file__.startswith('${prefix}') and c.shipped_config('mini').startswith('${prefix}')))")
endif()
