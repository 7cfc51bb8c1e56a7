%% @doc Internal. Whether the data directory (mnesia's, `EVATAR_DATA_DIR')
%% can take what the catalogue writes: `check/1' reserves
%% `data_dir_reserve_bytes' (default 1 MiB) in a probe file with
%% posix_fallocate, which takes blocks without writing them, and removes
%% it. A full file system (`enospc', or `edquot' past a quota) is
%% `{error, {disk_full, Dir}}'; any other failure is left to the writes
%% that meet it. Used by evatar_catalogue before each change and every
%% `disk_check_ms', and by node_config before mnesia starts
%% (docs/ha.md section 6, "A full disk").
-module(evatar_data_dir).

-export([check/1, ensure/1, reserve_bytes/0]).

-define(PROBE, ".evatar_space_probe").

%% @doc `ok' when `Dir' (made already, or not yet) has room for the
%% reserve, `{error, {disk_full, Dir}}' when it has not.
-spec check(file:filename()) -> ok | {error, {disk_full, file:filename()}}.
check(Dir) ->
    Probe = filename:join(Dir, ?PROBE),
    Result = case file:open(Probe, [write, raw, binary]) of
                 {ok, Fd} ->
                     R = reserve(Fd, reserve_bytes()),
                     _ = file:close(Fd),
                     R;
                 {error, _} = Error ->
                     Error
             end,
    _ = file:delete(Probe),
    case Result of
        {error, Full} when Full =:= enospc; Full =:= edquot -> {error, {disk_full, Dir}};
        _ -> ok
    end.

%% @doc Makes `Dir' with its parents when it is missing, readable by this
%% node's user only: it holds the pairings' credentials as stored and the
%% promises of the node's voter. mnesia makes its directory but not the
%% directory's parents (it would fail later, in its storage set-up).
-spec ensure(file:filename()) -> ok | {error, file:posix() | badarg}.
ensure(Dir) ->
    case filelib:is_dir(Dir) of
        true ->
            ok;
        false ->
            case filelib:ensure_dir(filename:join(Dir, "schema.DAT")) of
                ok -> file:change_mode(Dir, 8#700);
                {error, _} = Error -> Error
            end
    end.

%% A file system without fallocate (some network ones) is probed by
%% writing the reserve once.
reserve(Fd, Bytes) ->
    case file:allocate(Fd, 0, Bytes) of
        ok -> ok;
        {error, enotsup} -> file:write(Fd, binary:copy(<<0>>, Bytes));
        {error, _} = Error -> Error
    end.

%% @doc The room a catalogue change needs, `data_dir_reserve_bytes'.
-spec reserve_bytes() -> pos_integer().
reserve_bytes() ->
    case application:get_env(evatar, data_dir_reserve_bytes, 1048576) of
        N when is_integer(N), N > 0 -> N;
        _ -> 1048576
    end.
