#!/usr/bin/env bash
# Careless use: an output that names an input (directly, as ./x, dir/../x, or through
# a symbolic or hard link), two outputs that are the same file or one the other's temporary
# (<name>.partial), an output in a missing directory or
# with a directory under its name: refused before any work with one line, exit 2, nothing
# written and every input untouched. A generated family per program.
#   output_paths.sh crowd_fom|crowd_snapshots|crowd_offline|crowd_rom|crowd_predict EXECUTABLE
set -u
prog=$1; exe=$2
. "$(dirname "$0")/family_lib.sh"
base_model="&scene hall_length = 0.6, hall_width = 0.5, l_exit = 0.2, wall_thickness = 0.05 /
&agents n_agents = 8, radius = 0.04, speed = 1.0, seed = 3 /
&time dt = 0.02, n_steps = 10 /"
study="&study n_params = 1, param_name = 'l_exit', param_min = 0.18, param_max = 0.22, n_train = 2, n_valid = 1"
# write_input FILE OUT1 [OUT2]: the program's input with its outputs set
write_input() {
  local f=$1 o1=$2 o2=${3:-}
  case $prog in
    crowd_fom) printf '%s\n&output file = %s /\n' "$base_model" "'$o1'" > "$f";;
    crowd_snapshots) printf '%s\n%s, database = %s /\n' "$base_model" "$study" "'$o1'" > "$f";;
    crowd_offline) printf "%s\n%s, database = 'db.h5' /\n&offline database = 'db.h5', rom_file = %s /\n" \
      "$base_model" "$study" "'$o1'" > "$f";;
    crowd_rom) printf "&rom rom_file = 'rom.h5', database = 'db.h5', output = %s%s /\n&sweep n = 2, r = 2 /\n" "'$o1'" \
      "${o2:+, table = '$o2'}" > "$f";;
    crowd_predict) printf "&predict rom_file = 'rom.h5', output = %s, n = 2, r = 2, n_queries = 3 /\n" "'$o1'" > "$f";;
  esac
}
# inputs that must survive: the namelist, and the products the program reads
setup() {
  case_dir "$1"
  mkdir -p sub
  echo "precious database" > db.h5
  echo "precious rom" > rom.h5
}
same='is the input .*refusing to overwrite an input'
setup own_input;        write_input in.nml in.nml;            refused own_input "$same" "$exe" in.nml
setup dot_slash;        write_input in.nml ./in.nml;          refused dot_slash "$same" "$exe" in.nml
setup dot_dot;          write_input in.nml sub/../in.nml;     refused dot_dot "$same" "$exe" in.nml
setup symlink;          ln -s in.nml link.nml; write_input in.nml link.nml; refused symlink "$same" "$exe" in.nml
setup hard_link;        write_input in.nml hard.nml; ln in.nml hard.nml; refused hard_link "'hard.nml' $same" "$exe" in.nml
setup abs_path;         write_input in.nml "$PWD/in.nml";     refused abs_path "$same" "$exe" in.nml
setup summary_input;    write_input in.nml out.h5;            refused summary_input "--summary 'in.nml' $same" "$exe" in.nml --summary in.nml
setup summary_output;   write_input in.nml out.h5;            refused summary_output "--summary 'out.h5' and .* are the same file" "$exe" in.nml --summary out.h5
setup summary_partial;  write_input in.nml out.h5.partial;    refused summary_partial "--summary 'out.h5' and .* clash: one is the other's temporary" "$exe" in.nml --summary out.h5
setup missing_dir;      write_input in.nml nodir/out.h5;      refused missing_dir "the directory 'nodir' does not exist" "$exe" in.nml
setup is_directory;     write_input in.nml sub;               refused is_directory "'sub' is a directory" "$exe" in.nml
case $prog in
  crowd_offline|crowd_rom)
    setup database;     write_input in.nml db.h5;             refused database "'db.h5' $same" "$exe" in.nml
    setup database_link; ln -s db.h5 l.h5; write_input in.nml l.h5; refused database_link "'l.h5' $same" "$exe" in.nml;;
esac
case $prog in
  crowd_rom)
    setup rom_file;     write_input in.nml rom.h5;            refused rom_file "&rom output 'rom.h5' $same" "$exe" in.nml
    setup table_input;  write_input in.nml out.h5 in.nml;     refused table_input "&rom table 'in.nml' $same" "$exe" in.nml
    setup table_output; write_input in.nml out.h5 ./out.h5;   refused table_output "&rom table './out.h5' and &rom output 'out.h5' are the same file" "$exe" in.nml
    setup table_partial; write_input in.nml T.csv.partial T.csv; refused table_partial "&rom table 'T.csv' and &rom output 'T.csv.partial' clash" "$exe" in.nml;;
  crowd_predict)
    setup rom_file;     write_input in.nml rom.h5;            refused rom_file "&predict output 'rom.h5' $same" "$exe" in.nml;;
esac
finish
