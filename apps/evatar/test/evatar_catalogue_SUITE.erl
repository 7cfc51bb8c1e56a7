%% Common Test suite of the catalogue's data directory (EVATAR_DATA_DIR,
%% mnesia's directory), each case on a fresh node started with OTP's peer:
%% a directory whose parents are missing is made, private to the node's
%% user; one that cannot be made stops evatar with an error naming it. And
%% a pairing whose only instance stepped down is restored (issue 18).
-module(evatar_catalogue_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("kernel/include/file.hrl").

-export([all/0, suite/0, data_dir_is_made_private/1, unusable_data_dir_stops/1,
         stepped_down_is_restored/1]).

suite() -> [{timetrap, {minutes, 2}}].

all() -> [data_dir_is_made_private, unusable_data_dir_stops, stepped_down_is_restored].

%% A data directory two levels below anything that exists is made, with
%% mode 0700, and the catalogue is durable in it.
data_dir_is_made_private(Config) ->
    Dir = filename:join([?config(priv_dir, Config), "absent", "parents", "data"]),
    with_node(Dir, fun(Peer) ->
                           {ok, _} = peer:call(Peer, application, ensure_all_started, [evatar]),
                           true = peer:call(Peer, evatar_catalogue, durable, []),
                           {ok, _} = peer:call(Peer, evatar, create_pairing,
                                               [<<"kept">>, #{agent_credential => <<"a">>,
                                                              avatar_credential => <<"b">>}]),
                           {ok, #file_info{type = directory, mode = Mode}} =
                               file:read_file_info(Dir),
                           8#700 = Mode band 8#777,
                           true = filelib:is_regular(filename:join(Dir, "schema.DAT"))
                   end).

%% A data directory below a regular file cannot be made: evatar does not
%% start, and the reason names the directory.
unusable_data_dir_stops(Config) ->
    File = filename:join(?config(priv_dir, Config), "a-file"),
    ok = file:write_file(File, <<"not a directory">>),
    Dir = filename:join(File, "data"),
    with_node(Dir, fun(Peer) ->
                           {error, Why} = peer:call(Peer, application, ensure_all_started,
                                                    [evatar]),
                           ct:log("~p", [Why]),
                           Text = lists:flatten(io_lib:format("~p", [Why])),
                           true = string:find(Text, "data_dir_unusable") =/= nomatch,
                           true = string:find(Text, Dir) =/= nomatch
                   end).

%% An active that stops on purpose (it stepped down for a newer instance,
%% or its claim was stale) leaves its pairing with no instance when the
%% newer one is gone too: the catalogue starts it again, although the node
%% ran it (a node does not restore what crashed past its restart limit).
stepped_down_is_restored(Config) ->
    Dir = filename:join(?config(priv_dir, Config), "data"),
    with_node(Dir, fun(Peer) ->
                           {ok, _} = peer:call(Peer, application, ensure_all_started, [evatar]),
                           Id = <<"stepped">>,
                           {ok, _} = peer:call(Peer, evatar, create_pairing,
                                               [Id, #{agent_credential => <<"a">>,
                                                      avatar_credential => <<"b">>}]),
                           Pid = peer:call(Peer, evatar_registry, whereis_name, [Id]),
                           true = is_pid(Pid),
                           %% The catalogue has seen it run here (it watches it).
                           ok = evatar_test_wait:until(
                                  fun() -> watched(Peer, Pid) end,
                                  #{what => {catalogue_watches, Pid}}),
                           ok = peer:call(Peer, gen_statem, stop,
                                          [Pid, {shutdown, {newer_instance, gone@nowhere, 2}},
                                           5000]),
                           ok = evatar_test_wait:until(
                                  fun() ->
                                          New = peer:call(Peer, evatar_registry, whereis_name,
                                                          [Id]),
                                          is_pid(New) andalso New =/= Pid
                                  end, #{what => {restored, Id}})
                   end).

%% Whether the catalogue monitors `Pid' (it watches it: its rules'
%% started/3 or look/2 said so).
watched(Peer, Pid) ->
    Catalogue = peer:call(Peer, erlang, whereis, [evatar_catalogue]),
    {monitors, Monitors} = peer:call(Peer, erlang, process_info, [Catalogue, monitors]),
    lists:member({process, Pid}, Monitors).

with_node(Dir, Fun) ->
    Paths = lists:append([["-pa", P] || P <- code:get_path()]),
    {ok, Peer, _Node} = peer:start_link(#{connection => standard_io,
                                          args => ["-mnesia", "dir", "\"" ++ Dir ++ "\""
                                                   | Paths]}),
    try Fun(Peer)
    after peer:stop(Peer)
    end.
