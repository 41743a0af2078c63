# CMake toolchain file: cross-compiles the FMU binaries for 64-bit Windows with mingw-w64 on Linux
# (Debian: gcc-mingw-w64-x86-64, which scripts/setup.sh installs). The top-level CMakeLists.txt uses it
# for its win64 sub-build; by hand:
#   cmake -S . -B build-win64 -DCMAKE_TOOLCHAIN_FILE=cmake/mingw-w64-x86_64.cmake -DFMI_HEADERS_DIR=<fmpy/c-code>
#   cmake --build build-win64 --target maglev maglev3 maglev_pid fmi_importer test_fmu test_fmi3 test_pid_fmu test_replay
#   (cd build-win64 && ctest)     # the C tests, under wine when it is installed
set(CMAKE_SYSTEM_NAME Windows)
set(CMAKE_SYSTEM_PROCESSOR x86_64)
set(MINGW_TRIPLET x86_64-w64-mingw32)
find_program(CMAKE_C_COMPILER NAMES ${MINGW_TRIPLET}-gcc ${MINGW_TRIPLET}-gcc-win32 ${MINGW_TRIPLET}-gcc-posix REQUIRED)
find_program(CMAKE_RC_COMPILER NAMES ${MINGW_TRIPLET}-windres)
set(CMAKE_FIND_ROOT_PATH /usr/${MINGW_TRIPLET})
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)   # host tools (python, wine)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
# libgcc linked statically: the DLLs import only Windows' own DLLs (KERNEL32, msvcrt), no mingw runtime DLL
set(CMAKE_SHARED_LINKER_FLAGS_INIT "-static-libgcc")
set(CMAKE_EXE_LINKER_FLAGS_INIT "-static-libgcc")
# Release binaries without their symbol tables (the DLL exports are kept)
set(CMAKE_SHARED_LINKER_FLAGS_RELEASE_INIT "-s")
set(CMAKE_EXE_LINKER_FLAGS_RELEASE_INIT "-s")
# wine, when present, runs the cross-compiled executables (CMakeLists.txt: CMAKE_CROSSCOMPILING_EMULATOR)
