!> Unit tests of the core helpers: contact set algebra (B, B^T, Gershgorin bound, keys).
program test_core
  use cr_kinds, only: wp
  use cr_assert, only: check, check_close, test_summary
  use cr_contact_set, only: contact_set_t, contact_key
  implicit none
  type(contact_set_t) :: cs
  real(wp) :: u(6), lam(3), bu(3), btl(6), lhs, rhs
  call cs%init(3, 0.1_wp)
  call cs%add(1, 2, 0, [1.0_wp, 0.0_wp], 0.01_wp)
  call cs%add(2, 0, 4, [0.0_wp, 1.0_wp], 0.02_wp)
  call cs%add(1, 3, 0, [0.6_wp, 0.8_wp], 0.03_wp)
  u = [1.0_wp, 2.0_wp, 3.0_wp, 4.0_wp, 5.0_wp, 6.0_wp]
  lam = [0.5_wp, 1.5_wp, 2.0_wp]
  call cs%apply_b(u, bu)
  call check_close(bu(1), -0.1_wp * (1.0_wp - 3.0_wp), 1e-14_wp, "B row pair")
  call check_close(bu(2), -0.1_wp * 4.0_wp, 1e-14_wp, "B row obstacle")
  call cs%apply_bt(lam, btl)
  lhs = dot_product(lam, bu); rhs = dot_product(btl, u)
  call check_close(lhs, rhs, 1e-13_wp, "adjoint identity <lam, B u> = <B^T lam, u>")
  call check_close(cs%lipschitz_bound(), 0.01_wp * 4.0_wp, 1e-15_wp, "Gershgorin bound (row 1 touches 2+2 rows)")
  call check(contact_key(2, 1, 0) == contact_key(1, 2, 0), "pair key symmetric")
  call check(contact_key(1, 0, 1) /= contact_key(1, 1, 0), "obstacle key distinct")
  call check(contact_key(1, 0, 1) < contact_key(2, 3, 0), "keys ordered by first agent")
  call check(cs%key(2) == contact_key(2, 0, 4), "row key")
  call test_summary()
end program test_core
