# bash completion for voxlat. Source it (`. tools/completion/voxlat.bash`) or install it as
# share/bash-completion/completions/voxlat. Subcommands and options are listed here (CLI11
# generates none); printer names come from `voxlat printers`.

_voxlat()
{
    local cur prev words cword
    _init_completion 2>/dev/null || {
        cur="${COMP_WORDS[COMP_CWORD]}"
        prev="${COMP_WORDS[COMP_CWORD - 1]}"
        words=("${COMP_WORDS[@]}")
        cword=$COMP_CWORD
    }
    local commands="run mesh info sample schema check slice properties printers"
    local global="--threads -q --quiet --version -h --help"
    local command="" w
    for w in "${words[@]:1:cword-1}"; do
        case " $commands " in *" $w "*) command=$w; break ;; esac
    done

    case "$prev" in
    --printer)
        COMPREPLY=($(compgen -W "$(voxlat printers 2>/dev/null | awk 'NR > 1 && !/^\(/ {print $1}')" -- "$cur"))
        COMPREPLY+=($(compgen -f -X '!*.yaml' -- "$cur"))
        return ;;
    --format)
        COMPREPLY=($(compgen -W "sl1 sl1s zip png exr goo ctb cbddlp photon pwmo pwms pwma pwmx pmsq pwmb px6s pmx2 pm3 pm3m pm3r pm3n pm4n pm5 pm5s m5sp pws pw0 pwx dlp dl2p pm7 pm7m pm4u pp1 pp1m" -- "$cur"))
        return ;;
    --aa | --project | --refine | --strict | --preview)
        COMPREPLY=($(compgen -W "on off" -- "$cur"))
        return ;;
    --extractor)
        COMPREPLY=($(compgen -W "marching-cubes bcc" -- "$cur"))
        return ;;
    --out)
        COMPREPLY=($(compgen -d -- "$cur"))
        return ;;
    -o | --output | --json | --png)
        COMPREPLY=($(compgen -f -- "$cur"))
        return ;;
    --threads | --set | --layer | --gamma | --position | --tolerance | --field | --repeat | --sweep | --curve)
        return ;;
    esac

    local options=""
    case "$command" in
    "") COMPREPLY=($(compgen -W "$commands $global" -- "$cur")); return ;;
    run) options="--set --out --no-preview" ;;
    mesh) options="--set -o --output --tolerance --project --refine --strict --extractor" ;;
    info) options="--set --exact" ;;
    sample) options="--set --field --gradient" ;;
    schema) options="--markdown" ;;
    check) options="--set --repeat" ;;
    slice) options="--set --printer -o --output --layer --aa --gamma --position --format --preview" ;;
    properties) options="--set --json --png --sweep --curve" ;;
    printers) options="" ;;
    esac
    if [[ "$cur" == -* || "$command" == schema || "$command" == printers ]]; then
        COMPREPLY=($(compgen -W "$options $global" -- "$cur"))
    else
        COMPREPLY=($(compgen -f -X '!*.y*ml' -- "$cur") $(compgen -d -- "$cur"))
    fi
}
complete -F _voxlat voxlat
