#!/usr/bin/env bash
# Hostile namelist values (Inf, NaN, 1e308, 1e-308, 2147483647) are
# refused by each program with one line, exit 2, nothing written; never a crash or a hang.
#   hostile_values.sh crowd_fom|crowd_snapshots|crowd_offline|crowd_rom|crowd_predict EXECUTABLE
set -u
prog=$1; exe=$2
. "$(dirname "$0")/family_lib.sh"
# one input per case: the base groups with `extra` appended inside group `g`
make_input() {  # g extra [g2 extra2]
  local g=$1 extra=$2 g2=${3:-} extra2=${4:-}
  declare -A grp=(
    [scene]="hall_length = 0.6, hall_width = 0.5, l_exit = 0.2, wall_thickness = 0.05"
    [obstacles]="n_disks = 1, disk_x = 0.3, disk_y = 0.25, disk_r = 0.05"
    [agents]="n_agents = 8, radius = 0.04, speed = 1.0, seed = 3"
    [time]="dt = 0.02, n_steps = 10"
    [solver]="tol = 1e-10"
    [contacts]="cutoff_factor = 1.5"
    [desired]="field = 'auto'"
    [output]="file = 'out.h5'"
    [study]="n_params = 1, param_name = 'l_exit', param_min = 0.18, param_max = 0.22, n_train = 2, n_valid = 1, database = 'db.h5'"
    [offline]="database = 'db.h5', rom_file = 'rom.h5'"
    [pod]="method = 'tsqr'"
    [cone]="method = 'gis'"
    [pga]="enabled = .true."
    [hyper]="enabled = .true."
    [rom]="rom_file = 'rom.h5', output = 'rom_out.h5'"
    [sweep]="n = 2, r = 2"
    [reduced]="solver = 'dual'"
    [fom_timing]="samples = 1"
    [predict]="rom_file = 'rom.h5', output = 'pred.h5', n = 2, r = 2, n_queries = 3"
  )
  local groups="scene obstacles agents time solver contacts desired output"
  case $prog in
    crowd_snapshots) groups="$groups study";;
    crowd_offline) groups="$groups study offline pod cone pga hyper";;
    crowd_rom) groups="rom sweep reduced fom_timing";;
    crowd_predict) groups="predict";;
  esac
  for k in $groups; do
    if [ "$k" = "$g" ]; then echo "&$k ${grp[$k]}, $extra /"
    elif [ "$k" = "$g2" ]; then echo "&$k ${grp[$k]}, $extra2 /"
    else echo "&$k ${grp[$k]} /"; fi
  done
}
run_case() {  # name group extra regex [group2 extra2]
  case_dir "$1"
  make_input "$2" "$3" "${5:-}" "${6:-}" > in.nml
  refused "$1: &$2 $3" "$4" "$exe" in.nml
}
fin='must be a finite number'; big='beyond the sane magnitude'; small='is below'
case $prog in
  crowd_fom|crowd_snapshots|crowd_offline)
    run_case hall_tiny scene "hall_length = 1e-308" "&scene: hall_length = .*$small"
    run_case hall_huge scene "hall_length = 1e300" "&scene: hall_length = .*$big"
    run_case width_inf scene "hall_width = Inf" "&scene: hall_width $fin"
    run_case exit_nan scene "l_exit = NaN" "&scene: l_exit $fin"
    run_case wall_ninf scene "wall_thickness = -Inf" "&scene: wall_thickness $fin"
    run_case disk_inf obstacles "disk_r = Inf" "&obstacles: disk_r\\(1\\) $fin"
    run_case disk_x_huge obstacles "disk_x = 1e308" "&obstacles: disk_x\\(1\\) = .*$big"
    run_case speed_huge agents "speed = 1e308" "&agents: speed = .*$big"
    run_case speed_inf agents "speed = Inf" "&agents: speed $fin"
    run_case speed_nan agents "speed = NaN" "&agents: speed $fin"
    run_case radius_tiny agents "radius = 1e-300" "&agents: radius = .*$small"
    run_case region_inf agents "region = 0, 0, Inf, 0.5" "&agents: region\\(3\\) $fin"
    run_case dt_inf time "dt = Inf" "&time: dt $fin"
    run_case dt_tiny time "dt = 1e-300" "&time: dt = .*$small"
    run_case steps_max time "n_steps = 2147483647" "&time: n_steps = 2147483647 exceeds"
    run_case max_steps_max time "until_empty = .true., max_steps = 2147483647" "&time: max_steps = 2147483647 exceeds"
    run_case tol_inf solver "tol = Inf" "&solver: tol $fin"
    run_case tol_nan solver "tol = NaN" "&solver: tol $fin"
    run_case tol_huge solver "tol = 1e300" "&solver: tol = .*$big"
    run_case rho_inf solver "uzawa_rho_factor = Inf" "&solver: uzawa_rho_factor $fin"
    run_case cutoff_inf contacts "cutoff_factor = Inf" "&contacts: cutoff_factor $fin"
    run_case grid_tiny desired "field = 'grid', grid_dx = 1e-300" "&desired: grid_dx = .*$small"
    run_case grid_huge_cells desired "field = 'grid', grid_dx = 1e-5" "distance field grid .* cells"
    ;;
esac
case $prog in
  crowd_snapshots)
    run_case train_max study "n_train = 2147483647" "&study: n_train = 2147483647 exceeds"
    run_case valid_max study "n_valid = 2147483647" "&study: n_valid = 2147483647 exceeds"
    run_case snapshots_overflow time "n_steps = 9000000" "\\(n_train \\+ n_valid\\) \\* n_steps = .* exceeds" study "n_train = 300"
    run_case param_inf study "param_max = Inf" "&study: param_max\\(1\\) $fin"
    run_case param_nan study "param_min = NaN" "&study: param_min\\(1\\) $fin"
    run_case grid_overflow study "n_params = 2, param_name = 'l_exit', 'speed', param_min = 0.18, 0.5, param_max = 0.22, 1.5, sampling = 'grid', grid_n = 2147483647, 4" "grid_n gives .* training samples"
    ;;
  crowd_offline)
    run_case pod_energy_nan pod "energy = NaN" "&pod: energy $fin"
    run_case cone_delta_inf cone "delta = Inf" "&cone: delta $fin"
    run_case pga_delta_huge pga "delta = 1e308" "&pga: delta = .*$big"
    run_case hyper_m_inf hyper "m_factor = Inf" "&hyper: m_factor $fin"
    run_case eq_tol_nan hyper "eq_tol = NaN" "&hyper: eq_tol $fin"
    ;;
  crowd_rom)
    run_case mu_inf rom "sets = 'given', mu = Inf" "&rom: mu\\(1\\) $fin"
    run_case mu_huge rom "sets = 'given', mu = 1e308" "&rom: mu\\(1\\) = .*$big"
    run_case mu_nan rom "sets = 'given', mu = 0.2, NaN" "&rom: mu\\(2\\) $fin"
    run_case rho_inf reduced "uzawa_rho_factor = Inf" "&reduced: uzawa_rho_factor $fin"
    run_case eps_nan reduced "uzawa_eps = NaN" "&reduced: uzawa_eps $fin"
    run_case fom_tol_inf fom_timing "tol = Inf" "&fom_timing: tol $fin"
    ;;
  crowd_predict)
    dn="dist_param = 'l_exit', dist = 'normal'"
    run_case dist_a_inf predict "$dn, dist_a = Inf, dist_b = 0.1" "&predict: dist_a\\(1\\) $fin"
    run_case dist_b_nan predict "$dn, dist_a = 0.2, dist_b = NaN" "&predict: dist_b\\(1\\) $fin"
    run_case dist_a_huge predict "$dn, dist_a = 1e308, dist_b = 0.1" "&predict: dist_a\\(1\\) = .*$big"
    run_case dist_lo_ninf predict "dist_param = 'l_exit', dist = 'truncnormal', dist_a = 0.2, dist_b = 0.1, dist_lo = -Inf, dist_hi = 1" "&predict: dist_lo\\(1\\) $fin"
    run_case queries_negative predict "n_queries = -1" "&predict: .*n_queries must be >= 0"
    ;;
esac
# a lone '&' (a group without its name) in the file, whichever program reads it
case_dir lone_ampersand; { make_input none ""; echo "&"; } > in.nml
refused "lone '&' line" "in.nml: line [0-9]+: '&' without a group name" "$exe" in.nml
case_dir lone_ampersand_first; { echo "  &  "; make_input none ""; } > in.nml
refused "lone '&' first" "in.nml: line 1: '&' without a group name" "$exe" in.nml
# crowd_rom's groups in a file another program reads are checked like every other group
case $prog in
  crowd_fom|crowd_snapshots|crowd_offline)
    case_dir sweep_misspelt; { make_input none ""; echo "&sweep bogus = 1 /"; } > in.nml
    refused "&sweep misspelt" "namelist group &sweep: .*bogus" "$exe" in.nml
    case_dir sweep_text; { make_input none ""; echo "&sweep n = 'two' /"; } > in.nml
    refused "&sweep text" "namelist group &sweep" "$exe" in.nml
    case_dir reduced_misspelt; { make_input none ""; echo "&reduced solverr = 'dual' /"; } > in.nml
    refused "&reduced misspelt" "namelist group &reduced: .*solverr" "$exe" in.nml
    ;;
esac
finish
