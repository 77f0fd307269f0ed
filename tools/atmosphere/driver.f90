! Runs LOWTRAN7 in its classic mode: the routine reads its input cards from ./TAPE5 (and writes its listings to
! ./out/TAPE6, TAPE7 and TAPE8, which must exist), and this program prints, per wavenumber, the wavenumber (cm-1),
! the total transmittance and the path's thermal radiance (W cm-2 sr-1 um-1), one line each.
program irsim_lowtran
  implicit none
  integer, parameter :: nmax = 20000
  real, allocatable :: tx(:,:), irrad(:,:), v(:), alam(:), trace(:), unif(:), suma(:), sumvv(:)
  real :: zmdl(1), p(1), t(1), wmol(12)
  integer :: i
  allocate(tx(nmax,63), irrad(nmax,3), v(nmax), alam(nmax), trace(nmax), unif(nmax), suma(nmax), sumvv(nmax))
  v = -1.0
  tx = 0.0
  sumvv = 0.0
  zmdl = 0.0
  p = 0.0
  t = 0.0
  wmol = 0.0
  call lwtrn7(.false., nmax, 0., 0., 0., tx, v, alam, trace, unif, suma, irrad, sumvv, &
              0, 0, 0, 0, 0, 1, 0, zmdl, p, t, wmol, 0., 0., 0., 0.)
  do i = 1, nmax
    if (v(i) < 0.0) exit
    write(*,'(ES17.9E3,1X,ES17.9E3,1X,ES17.9E3)') v(i), tx(i,1), sumvv(i)
  end do
end program irsim_lowtran
