!> JSON writer: nesting, escaping, null for non-finite reals, atomic file write.
program test_json
  use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan, ieee_positive_inf
  use cr_kinds, only: wp, i8
  use cr_error, only: error_t
  use cr_assert, only: check, test_summary
  use cr_fsys, only: file_exists
  use cr_json, only: json_writer_t, json_escape
  implicit none
  type(json_writer_t) :: js
  type(error_t), allocatable :: error
  character(len=:), allocatable :: text, expected
  character(len=4096) :: buf
  integer :: unit, n
  real(wp) :: nan, inf

  nan = ieee_value(1.0_wp, ieee_quiet_nan)
  inf = ieee_value(1.0_wp, ieee_positive_inf)
  call check(json_escape('a"b\c' // achar(10) // achar(1)) == '"a\"b\\c\n\u0001"', "escape")

  call js%add("name", 'he said "hi" \o/')
  call js%add("n", 42)
  call js%add("big", 2_i8**40)
  call js%add("x", 0.5_wp)
  call js%add("ok", .true.)
  call js%begin_object("timings")
  call js%add("fom", 1.25_wp)
  call js%add("bad", nan)
  call js%begin_object("empty")
  call js%end_object()
  call js%end_object()
  call js%add("v", [1.0_wp, inf, -2.0_wp])
  call js%add("idx", [1, 2, 3])
  text = js%to_string()
  expected = '{' // nl() // &
    '  "name": "he said \"hi\" \\o/",' // nl() // &
    '  "n": 42,' // nl() // &
    '  "big": 1099511627776,' // nl() // &
    '  "x": 5.0000000000000000E-001,' // nl() // &
    '  "ok": true,' // nl() // &
    '  "timings": {' // nl() // &
    '    "fom": 1.2500000000000000E+000,' // nl() // &
    '    "bad": null,' // nl() // &
    '    "empty": {}' // nl() // &
    '  },' // nl() // &
    '  "v": [1.0000000000000000E+000, null, -2.0000000000000000E+000],' // nl() // &
    '  "idx": [1, 2, 3]' // nl() // '}' // nl()
  call check(text == expected, "document text")
  if (text /= expected) print '(a)', text

  call js%write_file("summary.json", error)
  call check(.not. allocated(error), "write_file")
  call check(file_exists("summary.json") .and. .not. file_exists("summary.json.partial"), "renamed")
  open(newunit=unit, file="summary.json", access="stream", form="unformatted", action="read")
  inquire(unit=unit, size=n)
  read(unit) buf(1:n)
  close(unit)
  call check(buf(1:n) == expected, "file content")

  call js%reset()
  call js%begin_object("open")
  call js%write_file("unbalanced.json", error)
  call check(allocated(error), "unbalanced objects fail")
  call check(.not. file_exists("unbalanced.json"), "nothing written when unbalanced")
  call js%reset()
  call js%write_file("no_such_dir/x.json", error)
  call check(allocated(error), "unwritable path fails")
  if (allocated(error)) call check(index(error%message, "no_such_dir/x.json") > 0, "message names path")
  call test_summary()
contains
  function nl() result(c)
    character(len=1) :: c
    c = new_line('a')
  end function nl
end program test_json
