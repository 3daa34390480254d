# The engine alone, without the optional packages (the ctest BuildOptionsTest):
#   cmake -DSRC=<source dir> -DWORK=<scratch dir> -P tests/install/options.cmake
# configures the source with GoogleTest, Google Benchmark, pybind11, OpenMP, MPI, SUNDIALS and
# Node.js hidden from CMake: the configuration must succeed, say what it leaves out, and its
# paper-omp scheduler (built without OpenMP) and SUNDIALS' stand-in must compile; with CVT_REQUIRE_ALL=ON the
# same must fail naming what is missing; with every part turned off it must say nothing is
# left out for want of a package.
set(hide -DCMAKE_DISABLE_FIND_PACKAGE_GTest=ON -DCMAKE_DISABLE_FIND_PACKAGE_benchmark=ON
         -DCMAKE_DISABLE_FIND_PACKAGE_pybind11=ON -DCMAKE_DISABLE_FIND_PACKAGE_OpenMP=ON
         -DCMAKE_DISABLE_FIND_PACKAGE_MPI=ON -DCMAKE_DISABLE_FIND_PACKAGE_SUNDIALS=ON
         -DNODE_EXE=NODE_EXE-NOTFOUND)
function(configure dir expect_rc)
  file(REMOVE_RECURSE ${WORK}/${dir})
  execute_process(COMMAND ${CMAKE_COMMAND} -S ${SRC} -B ${WORK}/${dir} ${ARGN}
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL expect_rc AND NOT (expect_rc STREQUAL "fail" AND NOT rc EQUAL 0))
    message(FATAL_ERROR "BuildOptionsTest: configure ${dir} exited ${rc}:\n${out}${err}")
  endif()
  string(REGEX REPLACE "[ \n]+" " " out "${out}${err}")  # CMake folds long messages
  set(out "${out}" PARENT_SCOPE)
endfunction()
function(expect text)
  string(FIND "${out}" "${text}" at)
  if(at EQUAL -1)
    message(FATAL_ERROR "BuildOptionsTest: the configuration does not say \"${text}\":\n${out}")
  endif()
endfunction()

configure(bare 0 ${hide})
foreach(part "the tests left out: no GoogleTest" "the benchmarks left out: no Google Benchmark"
             "the Python module left out: no pybind11" "the paper-omp scheduler left out: no OpenMP found"
             "sweeps across MPI ranks left out: no MPI found"
             "SUNDIALS' integrators (cvode, arkode) left out: no SUNDIALS (libsundials-dev) found")
  expect("cvt-engine: ${part}")
endforeach()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK}/bare --target graph/paper_omp.cpp.o
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "BuildOptionsTest: paper_omp.cpp without OpenMP does not compile:\n${out}${err}")
endif()

execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK}/bare --target engine/ode/sundials.cpp.o
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "BuildOptionsTest: sundials.cpp without SUNDIALS does not compile:\n${out}${err}")
endif()

configure(required fail ${hide} -DCVT_REQUIRE_ALL=ON)
expect("CVT_REQUIRE_ALL is ON")

configure(off 0 ${hide} -DCVT_BUILD_TESTS=OFF -DCVT_BUILD_BENCHMARKS=OFF -DCVT_BUILD_PYTHON=OFF
          -DCVT_BUILD_VIEWER=OFF -DCVT_WITH_MPI=OFF -DCVT_WITH_OPENMP=OFF -DCVT_WITH_SUNDIALS=OFF
          -DCVT_REQUIRE_ALL=ON)
string(FIND "${out}" "left out" at)
if(NOT at EQUAL -1)
  message(FATAL_ERROR "BuildOptionsTest: parts turned off are reported as left out:\n${out}")
endif()
file(REMOVE_RECURSE ${WORK})
