%% @doc Internal. Application callback: reads the node configuration file
%% (node_config:file/0) and fills the other applications' environment
%% before they start, or stops the node's start with the file's mistakes.
-module(node_config_app).
-behaviour(application).

-include_lib("kernel/include/logger.hrl").

-export([start/2, stop/1]).

-define(DISK_POLL_MS, 1000).
-define(DISK_FULL_REPEAT_MS, 60000).

-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    ok = await_data_dir_room(),
    case node_config:file() of
        none ->
            ?LOG_NOTICE(#{what => no_node_config,
                          message => <<"no configuration file (EVATAR_CONFIG unset, no etc/evatar.config)">>}),
            node_config_sup:start_link();
        {_, File} ->
            case node_config:load(File) of
                {ok, Config} ->
                    ok = node_config:apply_env(Config),
                    ?LOG_NOTICE(#{what => node_config_loaded, file => File,
                                  listeners => listeners(Config),
                                  pairings => [Id || #{id := Id} <- maps:get(pairings, Config)],
                                  mqtt_avatars => [Id || #{entity_id := Id}
                                                             <- maps:get(mqtt_avatars, Config)],
                                  wot_avatars => [Id || #{entity_id := Id}
                                                            <- maps:get(wot_avatars, Config)]}),
                    node_config_sup:start_link();
                {error, Reason} ->
                    %% Said on the console too: a node started by
                    %% `bin/evatar foreground' or a service manager shows
                    %% it there, before the boot's own crash report.
                    Text = node_config:format_error(Reason),
                    io:put_chars(standard_error, ["EVATAR will not start: the configuration file has "
                                                  "mistakes\n", Text]),
                    ?LOG_ERROR(#{what => bad_node_config, file => File, problems => element(3, Reason)}),
                    refuse_boot(Reason)
            end
    end.

-spec stop(term()) -> ok.
stop(_State) ->
    ok.

%% mnesia, which starts after this application, cannot start over a full
%% data directory: it dies (an erl_crash.dump) and may delete its log as
%% corrupt, the catalogue of pairings with it. So the boot waits here,
%% before mnesia, saying why, until there is room; then it goes on
%% (docs/ha.md section 6, "A full disk").
await_data_dir_room() ->
    case evatar:check_data_dir() of
        ok ->
            ok;
        {error, {disk_full, Dir}} ->
            io:put_chars(standard_error, ["EVATAR is waiting to start: its data directory ", Dir,
                                          " is full (free some space there)\n"]),
            await_data_dir_room(Dir, erlang:monotonic_time(millisecond) - ?DISK_FULL_REPEAT_MS)
    end.

await_data_dir_room(Dir, LastSaid) ->
    Now = erlang:monotonic_time(millisecond),
    Said = case Now - LastSaid >= ?DISK_FULL_REPEAT_MS of
               true ->
                   ?LOG_ERROR(#{what => disk_full, dir => Dir, phase => boot,
                                hint => "EVATAR_DATA_DIR's file system is full: the node starts "
                                        "once there is room (the catalogue is kept as it is)"}),
                   _ = logger_std_h:filesync(default),
                   Now;
               false ->
                   LastSaid
           end,
    receive after ?DISK_POLL_MS -> ok end,
    case evatar:check_data_dir() of
        ok -> ?LOG_NOTICE(#{what => disk_space_back, dir => Dir, phase => boot});
        {error, {disk_full, _}} -> await_data_dir_room(Dir, Said)
    end.

%% While the boot script starts the release's applications (its progress
%% is applications_loaded until they all run), a refused start would take
%% the node down with "Kernel pid terminated" and an erl_crash.dump: the
%% mistakes are said, so stop there with status 1. Started otherwise (a
%% test node, application:start/1), the caller gets the error.
refuse_boot(Reason) ->
    case init:get_status() of
        {starting, applications_loaded} ->
            _ = logger_std_h:filesync(default),
            erlang:halt(1);
        _ ->
            {error, Reason}
    end.

listeners(#{listeners := undefined}) -> from_environment;
listeners(#{listeners := Ls}) -> length(Ls).
